"""physmocap: physics-based monocular 3D human motion capture."""
__version__ = "0.1.0"
