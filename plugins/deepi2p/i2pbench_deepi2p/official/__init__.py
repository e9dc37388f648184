"""DeepI2P's network as its authors wrote it (lijx10/DeepI2P `models/networks_united.py` and the modules it uses),
its training losses, its solvers and the import of its checkpoints: the method's `official` size."""
