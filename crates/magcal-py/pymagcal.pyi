"""magcal from Python: read a magnetometer log, calibrate it as `magcal calibrate` does, apply and
export the calibration. Every keyword is the command line's flag of the same name, checked by the
same parser, refused with the same one-line message."""

from os import PathLike
from typing import Optional, Sequence, Union

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
) -> Calibration:
    """Calibrates a log (a Log, a path read with the defaults, or an (n, 3) array of readings)."""

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
