"""Measurement runs: the table format, reading and checking a run, the measurement list, writing a run.

* :mod:`~sim2real.measurements.runs.format`: the format's signal kinds and limits, and the types of a run as read,
  as prepared, and of a measurement list's runs;
* :mod:`~sim2real.measurements.runs.reading`: a run's table and metadata read and checked against the format, then
  against a model;
* :mod:`~sim2real.measurements.runs.measurement_list`: the measurement list, its runs read once, its settings;
* :mod:`~sim2real.measurements.runs.writing`: a run written in the format.
"""

from sim2real.measurements.records import SensorPlacement
from sim2real.measurements.runs.format import (
    DEFAULT_CUTOFF_HZ, DEFAULT_FILTER_ORDER, DEFAULT_TORQUE_SENSOR, DEGREES_THRESHOLD_RAD, MAX_GRID_PER_SAMPLE,
    MAX_INCOMPLETE_FRACTION, MIN_DURATION_S, MIN_SAMPLES, SIGNAL_KINDS, MeasurementEntry, PreparedRun,
    Role, Run, RunSet, measured_after_drive, torque_sensor_of,
)
from sim2real.measurements.runs.measurement_list import load_measurement_list, measurement_settings, read_runs
from sim2real.measurements.runs.reading import check_run, file_row, load_run, read_run
from sim2real.measurements.runs.writing import write_run

__all__ = [
    "DEFAULT_CUTOFF_HZ", "DEFAULT_FILTER_ORDER", "DEFAULT_TORQUE_SENSOR", "DEGREES_THRESHOLD_RAD",
    "MAX_GRID_PER_SAMPLE", "MAX_INCOMPLETE_FRACTION", "MIN_DURATION_S", "MIN_SAMPLES", "SIGNAL_KINDS",
    "MeasurementEntry", "PreparedRun", "Role", "Run", "RunSet", "SensorPlacement", "check_run",
    "file_row", "load_measurement_list", "load_run", "measured_after_drive", "measurement_settings", "read_run",
    "read_runs", "torque_sensor_of", "write_run",
]
