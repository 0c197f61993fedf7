"""Dependency-free C bundles: a step or rollout Function (:mod:`uavdyn.deploy.bundle`) and the
real-time-iteration MPC with its own QP solver (:mod:`uavdyn.deploy.mpc_bundle`)."""

from uavdyn.deploy.bundle import (
    BundleSpec,
    doublet_controls,
    export_bundle,
    model_bundle_spec,
)

__all__ = ["BundleSpec", "model_bundle_spec", "doublet_controls", "export_bundle"]
