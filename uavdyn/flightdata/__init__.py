"""Flight data: sortie and dataset types, interchange format, checks, preprocessing, log import.

The public names of the submodules: :mod:`.sortie`, :mod:`.errors`, :mod:`.csvio` and
:mod:`.manifest` (the interchange format), :mod:`.dataset` (loading), :mod:`.checks`,
:mod:`.noise`, :mod:`.preprocess`, :mod:`.windows` (stretches restarted from a record),
:mod:`.ulog` (PX4 ULog) and :mod:`.alfa` (ALFA folders).
"""

from uavdyn.flightdata.alfa import import_alfa
from uavdyn.flightdata.checks import check_kinematics, check_values, kinematic_residual
from uavdyn.flightdata.csvio import export, read_csv, write_csv
from uavdyn.flightdata.dataset import Dataset, load_dataset
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.manifest import read_manifest, write_manifest
from uavdyn.flightdata.noise import excess_rmse, pitch_noise_std, white_noise_std
from uavdyn.flightdata.preprocess import Normalisation, lowpass, normalisation
from uavdyn.flightdata.sortie import SPLIT_NAMES, Sortie, csv_columns
from uavdyn.flightdata.ulog import import_ulog
from uavdyn.flightdata.windows import Windows, make_windows

__all__ = ["SPLIT_NAMES", "Dataset", "FlightDataError", "Normalisation", "Sortie",
           "check_kinematics", "check_values", "csv_columns", "excess_rmse", "export",
           "kinematic_residual", "load_dataset", "lowpass", "normalisation", "pitch_noise_std",
           "read_csv", "read_manifest", "white_noise_std", "write_csv", "write_manifest",
           "import_alfa", "import_ulog", "Windows", "make_windows"]
