"""Baselines run in jaxplan's harness, recorded as executed pieces so that the planner's
metrics, files and figures apply unchanged: orca.py (ORCA through RVO2's pyrvo, planar
fleets; ``[planner] method = "orca"``; the harness both ORCA engines share) and
orca3d.py (RVO2-3D's ORCA in JAX, planar or 3-D fleets without obstacles; ``method =
"orca3d"``).  pyrvo is imported only when "orca" runs.
"""
