"""Training RandLA-Net: the loop (:mod:`~jointseg.network.training.loop`) and what it calls
(its step, validation, checkpoints), its data sources, crop batches and augmentation. Imported
only by `jointseg train` and the tests (torch)."""
