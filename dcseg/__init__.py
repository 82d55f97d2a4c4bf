"""dcseg: decoupled open-set 3D segmentation of posed RGB-D captures with Gaussian splatting.

This top-level module stays import-light (no torch): the service imports ``dcseg.config``.
"""

__version__ = "0.1.0"
