"""Dependency-free C bundle of a step or rollout Function."""

from uavdyn.deploy.bundle import (
    BundleSpec,
    doublet_controls,
    export_bundle,
    model_bundle_spec,
)

__all__ = ["BundleSpec", "model_bundle_spec", "doublet_controls", "export_bundle"]
