"""Training RandLA-Net: the loop (:mod:`~jointseg.training.loop`) and what it calls
(its step, validation, checkpoints), its data sources, crop batches and augmentation,
self-training with the pipeline's own sure labels, and the shipped weights packed or blended.

A tool above the run time, beside :mod:`jointseg.fitting`, not inside :mod:`jointseg.network`:
self-training runs the pipeline and its frame stage, and generated rooms are training data, so
inside the network's floor these imports would run up (docs/ARCHITECTURE.md). Imported only by
`jointseg train`, `jointseg prepared`, `jointseg models pack|blend` and the tests (torch)."""
