"""eve3d: surface reconstruction with Gaussian Splatting and learnable stereo depth priors."""

__version__ = "0.1.0"
