"""The Gaussian library: the model, its rasteriser (``render``), densification, losses, the
training loop and its checkpoints, the training views and their neighbours. The pretrain,
joint, stereo and evaluate stages use it; it imports no stage."""
