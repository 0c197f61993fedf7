"""Thin, documented entry points for training the learned correction.

The training code itself lives in the package (:mod:`uavdyn.learned.train`, needs the
``[train]`` extra); this folder holds the command-line entry point and the exact recipe that
made the shipped weights (``ship_weights.py``).
"""
