"""Evaluation reports: plots (:mod:`.plots`) and markdown (:mod:`.markdown`)."""
