"""Vision: marker detection and pose (ArUco, ChArUco, diamonds, AprilTag), camera models,
pose uncertainty, marker maps and calibration."""
