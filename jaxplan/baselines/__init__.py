"""Baselines run in jaxplan's harness, recorded as executed pieces so that the planner's
metrics, files and figures apply unchanged: orca.py (ORCA through RVO2's pyrvo, planar
fleets; ``[planner] method = "orca"``).  pyrvo is imported only when a baseline runs.
"""
