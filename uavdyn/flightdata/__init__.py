"""Flight data: the Sortie/Dataset types, the interchange format (manifest + CSV), checks,
preprocessing, and import of PX4 ULog files and ALFA folders."""

from uavdyn.flightdata.dataset import (
    SPLIT_NAMES,
    Dataset,
    FlightDataError,
    Normalisation,
    Sortie,
    check_kinematics,
    check_values,
    csv_columns,
    excess_rmse,
    export,
    kinematic_residual,
    load_dataset,
    lowpass,
    normalisation,
    pitch_noise_std,
    read_csv,
    read_manifest,
    white_noise_std,
    write_csv,
    write_manifest,
)
from uavdyn.flightdata.ulog import import_alfa, import_ulog

__all__ = ["SPLIT_NAMES", "Dataset", "FlightDataError", "Normalisation", "Sortie",
           "check_kinematics", "check_values", "csv_columns", "excess_rmse", "export",
           "kinematic_residual", "load_dataset", "lowpass", "normalisation", "pitch_noise_std",
           "read_csv", "read_manifest", "white_noise_std", "write_csv", "write_manifest",
           "import_alfa", "import_ulog"]
