"""From markers to a DockPose: SolvePnP baselines, the planar fit, the papers' regression at run time, the fused
method, bundles, the Estimator."""
