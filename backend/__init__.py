"""Keyframes, loop closures, the pose graph and trajectory metrics."""
