"""What ``evaluate.py`` and ``demo.py`` run: the self-referenced fracture metrics of a
simulation (:mod:`.sim_eval`), static metrics of a trained model (:mod:`.static_eval`), the
paper's experiments (:mod:`.suites`: ablation, hardening, N_v sweep, momentum, energy) and the
local / Ray runner for independent simulations (:mod:`.runner`)."""
