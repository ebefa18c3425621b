"""Following controller and robot base drivers."""
