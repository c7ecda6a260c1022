"""magcal from Python: plan the attitudes a vehicle should visit (`design`), read a magnetometer
log, calibrate it as `magcal calibrate` does, judge it against a log's attitudes (`evaluate`),
ask which attitudes add most (`next`), apply and export the calibration. Every keyword is the command line's flag of the same name, checked by the
same parser, refused with the same one-line message."""

from os import PathLike
from typing import Any, Iterator, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str

class InputError(ValueError):
    """Bad input: a log, calibration or option refused (the command line's exit 2)."""

class UnusableError(Exception):
    """Not a calibration to use, where one is needed (the command line's exit 3)."""

class Log:
    """A log's readings and what was logged beside them, as `magcal` reads it."""

    @property
    def path(self) -> str: ...
    @property
    def readings(self) -> npt.NDArray[np.float64]:
        """The readings, shape (n, 3), in the log's units, before any calibration."""
    @property
    def lines(self) -> npt.NDArray[np.uint64]:
        """Each reading's 1-based CSV line, or its message's byte offset in a flight log."""
    @property
    def times(self) -> Optional[npt.NDArray[np.float64]]:
        """Each reading's time, seconds on the log's clock; None without times."""
    @property
    def attitudes(self) -> Optional[npt.NDArray[np.float64]]:
        """Shape (n, 3, 3): body into north, east, down; NaN where a reading has none."""
    @property
    def columns(self) -> list[str]: ...
    @property
    def format(self) -> str:
        """csv, dataflash, tlog or ulog."""
    @property
    def units(self) -> Optional[str]:
        """mG for ArduPilot, G for PX4, None where the format does not fix them."""
    @property
    def notes(self) -> list[str]: ...
    @property
    def sha256(self) -> str: ...
    @property
    def skipped(self) -> list[tuple[int, str]]: ...
    def __len__(self) -> int: ...

class Calibration:
    """A calibration as `magcal calibrate` makes it. Estimates raise UnusableError where no
    model fits the log (`fit` is then None)."""

    @property
    def usable(self) -> bool: ...
    @property
    def reasons(self) -> list[str]: ...
    @property
    def json(self) -> str:
        """What `magcal calibrate --json` prints for the same log and options, byte for byte."""
    @property
    def fit(self) -> Optional[str]: ...
    @property
    def verdict(self) -> Optional[str]: ...
    @property
    def heading_budget_deg(self) -> Optional[float]:
        """The heading budget it was judged against, degrees."""
    @property
    def heading_deg(self) -> Optional[float]:
        """The heading error it is predicted to leave (95th percentile over the vehicle's
        attitudes at every heading), degrees."""
    @property
    def heading_words(self) -> Optional[str]: ...
    @property
    def magnitude(self) -> float: ...
    @property
    def bias(self) -> npt.NDArray[np.float64]: ...
    @property
    def psi_deg(self) -> npt.NDArray[np.float64]: ...
    @property
    def scale(self) -> npt.NDArray[np.float64]: ...
    @property
    def k(self) -> npt.NDArray[np.float64]:
        """K of raw = K b + bias, shape (3, 3)."""
    @property
    def soft_iron_inverse(self) -> npt.NDArray[np.float64]:
        """calibrated = soft_iron_inverse @ (raw - bias), shape (3, 3)."""
    @property
    def std_error(self) -> dict[str, Optional[list[float]]]:
        """Standard errors of psi_deg, scale and bias; None where the information is singular."""
    @property
    def noise(self) -> Optional[float]: ...
    def apply(self, readings: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The readings, shape (n, 3), calibrated."""

def read_log(
    path: Union[str, PathLike[str]],
    *,
    format: Optional[str] = None,
    columns: Optional[str] = None,
    skip_bad: bool = False,
    where: Optional[Sequence[str]] = None,
    compass: Optional[int] = None,
    start: Optional[float] = None,
    end: Optional[float] = None,
    rate: Optional[float] = None,
    time: Optional[str] = None,
    time_unit: Optional[str] = None,
    euler: Optional[str] = None,
    quaternion: Optional[str] = None,
    attitude_frame: Optional[str] = None,
    current: Optional[str] = None,
    throttle: Optional[str] = None,
    position: Optional[str] = None,
    utc: Optional[str] = None,
    heading_from: Optional[str] = None,
) -> Log:
    """Reads a CSV log, an ArduPilot DataFlash log, a MAVLink telemetry log or a PX4 ULog.
    `start` and `end` are the flags `--from` and `--to`."""

def calibrate(
    log: Union[Log, str, PathLike[str], npt.ArrayLike],
    *,
    fit: Optional[str] = None,
    magnitude: Optional[float] = None,
    units: Optional[str] = None,
    site: Optional[str] = None,
    date: Optional[str] = None,
    wmm: Optional[str] = None,
    noise: Optional[float] = None,
    reject: Optional[float] = None,
    residual: Optional[str] = None,
    trials: Optional[int] = None,
    seed: Optional[int] = None,
    scenario: Optional[Union[str, PathLike[str]]] = None,
    heading_budget: Optional[float] = None,
) -> Calibration:
    """Calibrates a log (a Log, a path read with the defaults, or an (n, 3) array of readings);
    usable only where the heading it leaves is within `heading_budget` degrees (default 2)."""

def read_calibration(path: Union[str, PathLike[str]]) -> Calibration:
    """Reads a calibration.json written by `magcal calibrate --out` or `--json`."""

def export(
    calibration: Calibration,
    to: str,
    *,
    compass: Optional[int] = None,
    units: Optional[str] = None,
    offs_max: Optional[int] = None,
    strict: bool = False,
    force: bool = False,
) -> str:
    """The calibration as `magcal export --to TO` writes it: ardupilot, px4, motioncal, magneto
    or c."""

class Design:
    """One design of a plan: its attitudes in the order to fly them, its metrics and verdict."""

    @property
    def name(self) -> str: ...
    @property
    def kind(self) -> str:
        """optimum, pso, plan, grid, random or explicit (listed in the scenario)."""
    @property
    def m(self) -> int:
        """Readings in all."""
    @property
    def roll_deg(self) -> npt.NDArray[np.float64]: ...
    @property
    def pitch_deg(self) -> npt.NDArray[np.float64]: ...
    @property
    def yaw_deg(self) -> npt.NDArray[np.float64]:
        """From the field's horizontal direction ([P1]'s yaw)."""
    @property
    def magnetic_heading_deg(self) -> npt.NDArray[np.float64]: ...
    @property
    def readings(self) -> npt.NDArray[np.uint64]:
        """Readings to log at each attitude."""
    @property
    def quaternions(self) -> npt.NDArray[np.float64]:
        """Shape (k, 4), (w, x, y, z): body into north, east, down."""
    @property
    def d_efficiency(self) -> Optional[float]:
        """Per reading, against the best design of the plan."""
    @property
    def certified_efficiency(self) -> Optional[float]:
        """Lower bound against every design of as many readings in the box."""
    @property
    def identifiable(self) -> bool: ...
    @property
    def works(self) -> bool:
        """Calibrated in at least 95 % of the scenario's check trials, its heading within the budget
        (and 18 of 20 of its logs usable where design flew them)."""
    @property
    def heading_median_deg(self) -> Optional[float]: ...
    @property
    def heading_p95_deg(self) -> Optional[float]:
        """The 95th percentile of the heading error its check's calibrations leave over the box."""
    @property
    def logs_usable(self) -> Optional[int]:
        """Of 20 logs of it flown and judged as calibrate judges a log (where its heading is above
        half the budget), how many are usable; works needs 18. None where none were flown."""
    @property
    def metrics(self) -> dict[str, Any]:
        """Its row of design_metrics.csv (a copy)."""
    @property
    def points(self) -> list[dict[str, Any]]:
        """Its rows of designs.csv, in the order to fly them (copies)."""
    def __len__(self) -> int: ...

class Plan:
    """The designs of a scenario, as `magcal design` makes them."""

    @property
    def name(self) -> str: ...
    @property
    def designs(self) -> list[Design]: ...
    @property
    def recommended(self) -> Optional[Design]:
        """The design to fly; None when none works (see tables["advice.csv"])."""
    @property
    def recommendation(self) -> str:
        """As `magcal design` prints it."""
    @property
    def tables(self) -> dict[str, list[dict[str, Any]]]:
        """designs.csv, design_metrics.csv, approximate.csv, certificate.csv (and advice.csv
        when no design works), rows as dicts with the files' numbers (copies). Counts are
        ints, every other number a float."""
    def __getitem__(self, key: Union[str, int]) -> Design:
        """A design by name or by its place in the scenario."""
    def __contains__(self, name: object) -> bool: ...
    def __iter__(self) -> Iterator[Design]: ...
    def __len__(self) -> int: ...

def design(
    scenario: Optional[Union[str, PathLike[str]]] = None,
    *,
    toml: Optional[str] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    allow_long: bool = False,
) -> Plan:
    """The designs of a scenario file, or of its text (`toml=`, not both), as `magcal design`
    makes them. Ctrl-C is seen when the designs are done."""

def evaluate(
    calibration: Union[Calibration, str, PathLike[str], None],
    log: Union[str, PathLike[str]],
    **options: Any,
) -> dict[str, Any]:
    """`magcal evaluate CAL LOG --json` as a dict (None: `--raw LOG`). Options are the flags of
    the same name (quaternion="qw,qx,qy,qz", attitude_frame="enu", where=[...], start=, end=);
    a switch takes True or False, a repeated flag a list, a MIN,MAX flag a tuple or its text; an
    unknown keyword is a TypeError. The command line's warnings (rows skipped, a calibration
    marked not identifiable) arrive as UserWarning."""

def next(
    calibration: Union[Calibration, str, PathLike[str]],
    log: Union[str, PathLike[str]],
    **options: Any,
) -> dict[str, Any]:
    """`magcal next CAL LOG --json` as a dict: the attitudes that add most to the log, in the box
    of scenario= (or site=, date=, roll=(MIN, MAX), pitch=(MIN, MAX)), or a vector calibration's
    own manoeuvres. Keywords as for evaluate."""
