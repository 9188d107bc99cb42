"""Benchmark tasks on data sets shaped like a robot's, ROS-free (``pearl_bench`` runs them)."""
