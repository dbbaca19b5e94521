"""The output folders of the tools as the pipeline reads and writes them: a simulation folder
(sim_writer, sim_reader) and a train.py model folder (model_folder). Their layouts, and the
atomic writes, locks and manifests they use, are in ``fracture_gs.io``."""
