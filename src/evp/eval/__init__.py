"""Trajectory evaluation with evo's conventions: association, alignment, APE/RPE, statistics, plots."""
