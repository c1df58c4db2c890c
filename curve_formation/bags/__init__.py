"""Bags of a run: the ROS 2 bag format (bag), the recorded streams' names (streams), the
analysis of a bag into a run's folder (analysis), its replay (replay) and the link's latency
measured from it (measure_link).
"""
