"""Motion ControlNet (MotionLCM's control in motion space): network, hints, bundle kind, training."""
