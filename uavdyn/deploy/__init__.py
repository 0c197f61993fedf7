"""Dependency-free C bundle of a step or rollout Function."""

from uavdyn.deploy.bundle import BundleSpec, doublet_controls, export_bundle

__all__ = ["BundleSpec", "doublet_controls", "export_bundle"]
