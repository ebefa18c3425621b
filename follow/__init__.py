"""follow: monocular person following for mobile robots."""

__version__ = "0.1.0"
