"""DGCNN with dgcnn.pytorch's S3DIS weights: the model, its blocks and whole-scan inference, and
its torch-free backend record.

Empty on purpose: the registry imports :mod:`jointseg.network.dgcnn.backend` without torch.
"""
