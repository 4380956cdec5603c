"""RandLA-Net: the model, its crops and whole-scan inference, and its torch-free backend record.

Empty on purpose: the registry imports :mod:`jointseg.network.randlanet.backend` without torch.
"""
