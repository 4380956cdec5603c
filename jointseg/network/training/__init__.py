"""Training RandLA-Net: the loop (:mod:`~jointseg.network.training.loop`), its data sources,
crop batches and augmentation. Imported only by `jointseg train` and the tests (torch)."""
