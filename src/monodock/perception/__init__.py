"""From image to markers: ArUco detection, bias-free corner refinement, the papers' side-length features."""
