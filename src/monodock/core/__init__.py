"""The ground everything stands on: frames and poses, transforms, the camera and lens model, the dock layout, the
robot file, LaserScan, files."""
