"""Judging the methods: metrics, held-out evaluation, the physical limit, the robustness sweep, closed-loop dock-sim."""
