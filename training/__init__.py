"""Thin, documented entry points for training the learned correction.

The training code itself lives in the package (:mod:`uavdyn.learned.safe` for the safe
correction, :mod:`uavdyn.learned.train` for the paper's and the other legacy formulations,
:mod:`uavdyn.learned.command` for ``uavdyn train``; they need the ``[train]`` extra); this folder
holds the command-line entry point (``train.py``) and the exact recipe that made the shipped
identified airframes and safe corrections (``ship_safe.py``).
"""
