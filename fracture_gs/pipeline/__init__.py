"""The stages of the pipeline (train, simulate, render, evaluate, demo) as functions; the
command lines in ``fracture_gs.cli`` parse options and call them."""
