"""Dependency-free C bundle of a step or rollout Function."""

from uavdyn.deploy.bundle import (
    BundleSpec,
    airframe_bundle_spec,
    doublet_controls,
    export_bundle,
)

__all__ = ["BundleSpec", "airframe_bundle_spec", "doublet_controls", "export_bundle"]
