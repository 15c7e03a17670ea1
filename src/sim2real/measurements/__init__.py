"""Measurements: the runs of a robot, read, checked and prepared for the comparison with a model.

* :mod:`~sim2real.measurements.runs`: the table format, the ``Run``/``PreparedRun``/``MeasurementEntry`` types and
  the ``RunSet`` of a measurement list (its runs, each with its role), reading and checking a run, the measurement
  list, writing a run;
* :mod:`~sim2real.measurements.records`: what a run says of itself (``RunMeta``) and what its preparation did
  (``FilterSettings``), typed, each with the document it is written as;
* :mod:`~sim2real.measurements.cleaning`: what a logger got wrong (gaps, lone spikes, held columns), found and repaired;
* :mod:`~sim2real.measurements.prepare`: a run on a uniform grid, filtered, differentiated (the rule
  ``prepare_runs``);
* :mod:`~sim2real.measurements.noise`: the noise floors, measured once when a run is prepared and read back;
* :mod:`~sim2real.measurements.store`: the prepared runs on disk, read back by the sysid and gap report rules;
* :mod:`~sim2real.measurements.bags`: ROS 2 bags (MCAP) converted to runs (the rule ``bag_to_run``).
"""

from sim2real.measurements.noise import (  # noqa: F401  (re-exported: the package's names)
    command_floor_of, command_white_noise, noise_floor_of, white_noise_sigma,
)
from sim2real.measurements.prepare import (  # noqa: F401
    load_prepared_runs, prepare_for_model, prepare_run, prepare_runs, with_command_floor,
)
from sim2real.measurements.records import (  # noqa: F401
    FilterSettings, GapPiece, GapRecord, HeldRecord, IncompleteRows, LoggingGap, RunMeta, SpikeRecord, StepRange,
)
from sim2real.measurements.runs import (  # noqa: F401
    DEFAULT_TORQUE_SENSOR, SIGNAL_KINDS, MeasurementEntry, PreparedRun, Run, RunSet, SensorPlacement,
    check_run, load_measurement_list, load_run, measured_after_drive, measurement_settings, read_run, read_runs,
    torque_sensor_of, write_run,
)
from sim2real.measurements.store import (  # noqa: F401
    FIT_ARRAYS, PREPARED_SUFFIX, read_prepared_runs, runs_for_model, write_prepared_runs,
)
