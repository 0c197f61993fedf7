"""Flight data: sortie and dataset types, interchange format, checks, preprocessing, log import.

The public names of the submodules: :mod:`.sortie`, :mod:`.errors`, :mod:`.csvio` and
:mod:`.manifest` (the interchange format), :mod:`.dataset` (loading), :mod:`.checks`,
:mod:`.noise`, :mod:`.preprocess`, :mod:`.windows` (stretches restarted from a record),
:mod:`.ulog` (PX4 ULog) and :mod:`.alfa` (ALFA folders) as whole-log sorties; real logs as
six-degree-of-freedom flights (:mod:`.flightlog`; readers :mod:`.ulog_flight`, :mod:`.alfa`,
:mod:`.ardupilot`, :mod:`.sixdof_csv`) cut into longitudinal segments (:mod:`.segments`) and
written as a dataset with a split (:mod:`.log_dataset`, :mod:`.split`); several logs as one
campaign dataset on one rate (:mod:`.campaign`); the grid of a log whose attitude is slower
than its gyro (:mod:`.fast_grid`).
"""

from uavdyn.flightdata.alfa import import_alfa, read_alfa_flight
from uavdyn.flightdata.ardupilot import read_dataflash
from uavdyn.flightdata.campaign import CampaignRate, LogSource, find_logs, on_one_rate
from uavdyn.flightdata.checks import check_kinematics, check_values, kinematic_residual
from uavdyn.flightdata.control_map import ChannelMap, parse_channel_map
from uavdyn.flightdata.csvio import export, read_csv, write_csv
from uavdyn.flightdata.dataset import Dataset, load_dataset
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.fast_grid import GridChoice, fastest_grid, gyro_aided_attitude
from uavdyn.flightdata.flightlog import FlightLog, resample_flight
from uavdyn.flightdata.log_dataset import LogDataset, plan_log_dataset, write_log_dataset
from uavdyn.flightdata.manifest import read_manifest, write_manifest
from uavdyn.flightdata.noise import excess_rmse, pitch_noise_std, white_noise_std
from uavdyn.flightdata.preprocess import Normalisation, lowpass, normalisation
from uavdyn.flightdata.segments import SegmentReport, SegmentRules, find_segments, segment_sorties
from uavdyn.flightdata.sixdof_csv import read_sixdof_csv
from uavdyn.flightdata.sortie import SPLIT_NAMES, Sortie, csv_columns
from uavdyn.flightdata.split import SplitError, assign_split, split_dataset
from uavdyn.flightdata.ulog import import_ulog
from uavdyn.flightdata.ulog_flight import read_ulog_flight
from uavdyn.flightdata.windows import Windows, make_windows

__all__ = ["SPLIT_NAMES", "Dataset", "FlightDataError", "Normalisation", "Sortie",
           "check_kinematics", "check_values", "csv_columns", "excess_rmse", "export",
           "kinematic_residual", "load_dataset", "lowpass", "normalisation", "pitch_noise_std",
           "read_csv", "read_manifest", "white_noise_std", "write_csv", "write_manifest",
           "import_alfa", "import_ulog", "Windows", "make_windows", "ChannelMap",
           "parse_channel_map", "FlightLog", "resample_flight", "LogDataset",
           "write_log_dataset", "plan_log_dataset", "SegmentReport", "SegmentRules",
           "find_segments", "segment_sorties", "SplitError", "assign_split", "split_dataset",
           "read_alfa_flight", "read_dataflash", "read_sixdof_csv", "read_ulog_flight",
           "CampaignRate", "LogSource", "find_logs", "on_one_rate", "GridChoice",
           "fastest_grid", "gyro_aided_attitude"]
