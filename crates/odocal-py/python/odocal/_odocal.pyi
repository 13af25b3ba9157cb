"""Type stubs of the native module odocal._odocal (Rust, pyo3)."""

from os import PathLike
from typing import Any, Callable, Mapping, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str
#: Columns of ``Drive.to_numpy()``, in order.
COLUMNS: list[str]
#: The keyword options ``calibrate`` takes (the library's settings, then holdout, validate_on,
#: carry_heading_offset).
CALIBRATE_OPTIONS: tuple[str, ...]

_ArrayLike = npt.ArrayLike
_Path = Union[str, PathLike[str]]
_ThetaLike = Union[Mapping[str, float], Sequence[float], str]
_SigmaLike = Union[Mapping[str, float], Sequence[float]]

class OdocalError(ValueError):
    """An error of the odocal library (bad data, a bad option, a calibration
    that cannot run); the message is the library's."""

class Drive:
    """A drive: one uniformly sampled time series of reference poses and
    model inputs, checked by the library's constructor.

    Drives pickle exactly (columns, parts, sample time), so they can be sent
    to Ray tasks or multiprocessing workers.
    """

    @staticmethod
    def from_arrays(
        t: _ArrayLike,
        px: _ArrayLike,
        py: _ArrayLike,
        psi: _ArrayLike,
        n_rl: _ArrayLike,
        n_rr: _ArrayLike,
        a_y: _ArrayLike,
        beta: Optional[_ArrayLike] = None,
        part: Optional[_ArrayLike] = None,
        sample_time_s: Optional[float] = None,
    ) -> Drive:
        """Makes a drive from 1-D arrays (converted to float64): time t (s),
        reference pose px, py (m), psi (rad), rear wheel speeds n_rl, n_rr
        (rev/s), lateral acceleration a_y (m/s², positive left), sideslip
        beta (rad, default zeros) and per-sample part ids (non-negative
        integers, as the CSV's ``part`` column; whole floats are taken).

        Raises OdocalError naming the column and the sample (NaN, a length
        mismatch, time that does not increase, a non-uniform step, a part id
        that is a fraction or negative, ...), naming the argument, its shape
        and the 1-D array expected for one that is not 1-D (a 2-D array, a
        single number), naming an argument of more than 50,000,000
        samples before any is converted, and naming a numpy masked array
        with masked values (numpy would hand over the values under its mask)."""
    @staticmethod
    def from_csv(path: _Path) -> Drive:
        """Reads a canonical CSV; a simulator sidecar beside it gives the true θ."""
    @staticmethod
    def from_manifest(path: _Path) -> Drive:
        """Imports a multi-stream log described by a drive manifest (.toml)."""
    @staticmethod
    def load(path: _Path) -> Drive:
        """A canonical CSV, or a manifest when the path ends in .toml."""
    @property
    def columns(self) -> list[str]:
        """Names of the columns of ``to_numpy()``: t, px, py, psi, n_rl, n_rr, beta, a_y."""
    def to_numpy(self) -> npt.NDArray[np.float64]:
        """The measured columns as a (samples, 8) float64 array in ``columns`` order (psi unwrapped)."""
    def column(self, name: str) -> npt.NDArray[np.float64]:
        """One column: a name of ``columns``, a truth column (``px_true``, ...) or a numeric extra column."""
    def part_ids(self) -> npt.NDArray[np.int64]:
        """Per-sample part index 0, 1, ..."""
    @property
    def parts(self) -> list[tuple[int, int]]:
        """Continuous parts as (start, stop) sample indices."""
    @property
    def sample_time_s(self) -> float:
        """Sample time t_s, s."""
    @property
    def distance_m(self) -> float:
        """Reference path length, m."""
    @property
    def theta_true(self) -> Optional[dict[str, float]]:
        """The true θ of a simulated drive, else None."""
    @property
    def simulation(self) -> Optional[dict[str, Any]]:
        """The simulator sidecar (true θ, settings, statistics), else None."""
    @property
    def import_report(self) -> Optional[dict[str, Any]]:
        """The import report of a drive read from a manifest, else None."""
    @property
    def fingerprint(self) -> str:
        """SHA-256 (hex) of the canonical samples: the same for the same drive read from a CSV,
        imported through a manifest or made from arrays."""
    @property
    def source(self) -> Optional[str]:
        """The file the drive was read from (a CSV or a manifest), else None."""
    def to_csv(self, path: _Path) -> None:
        """Writes the canonical CSV (and the sidecar JSON of a simulated drive), atomically; a path
        that is one of the drive's own files raises OdocalError."""
    def __len__(self) -> int: ...

def calibrate(
    drive: Union[Drive, Sequence[Drive]],
    method: Optional[str] = None,
    *,
    progress: Optional[Callable[[str, int, int], Any]] = None,
    threads: Optional[int] = None,
    **options: Any,
) -> tuple[dict[str, Any], str]:
    """Calibrates; returns (report dict, report JSON text). Use odocal.calibrate."""

def validate(
    drive: Drive,
    theta: _ThetaLike,
    *,
    validation_length: Optional[int] = None,
    threads: Optional[int] = None,
    report_json: Optional[str] = None,
    carry_heading_offset: bool = False,
    params_node: Optional[str] = None,
    fit_drive: bool = True,
) -> dict[str, Any]:
    """Ē_p of θ on the validation segments of the drive (with ``report_json``, the extrinsics
    that report's calibration estimated). The drive's heading offset is re-estimated with θ
    held (``heading_offset_fit``) where the calibration estimated one or ``theta`` is numbers,
    unless ``carry_heading_offset``. ``fit_drive``: θ fitted on the drive and the verdict
    (``drive_fit``)."""

def simulate(
    seed: int = 0,
    length_km: float = 24.0,
    noise: str = "paper",
    *,
    theta: Optional[_ThetaLike] = None,
    substeps: Optional[int] = None,
) -> Drive:
    """Simulates a drive with known true θ (noise: paper, off, white or high); ``seed`` is an
    integer 0 … 2^64 − 1."""

def _drive_from_state(state: dict[str, Any]) -> Drive: ...
def _report_html(
    drive: Union[Drive, Sequence[Drive]],
    report_json: str,
    path: _Path,
    *,
    holdout: Optional[str] = None,
    validate_on: Optional[Union[Drive, Sequence[Drive]]] = None,
    title: Optional[str] = None,
    drives: Optional[Sequence[Drive]] = None,
) -> None: ...
def _method_details(report_json: str) -> str: ...
def read_params(path: _Path, *, params_node: Optional[str] = None) -> dict[str, Any]:
    """A parameter file (ROS 2 YAML or JSON, as ``--params-out`` writes it; the node ``params_node``,
    or the one node holding odocal's parameters) in the JSON file's layout:
    ``{"schema_version", "node", "parameters", "units", "verdict", "verdict_reasons", "provenance"}``
    (``verdict_reasons`` only when there are reasons: a missing key is none)."""
def _write_params(
    report_json: str,
    path: _Path,
    *,
    input: Optional[str] = None,
    node: str,
    mapping: str,
    drives: Optional[Sequence[Drive]] = None,
    calibration: Optional[Sequence[Drive]] = None,
) -> None: ...

class RawStream:
    """The streamed import (``odocal.online.RawStream``): a manifest's streams pushed
    message by message, canonical samples taken as they become ready. A call from another
    thread while a push runs (without the GIL) waits for it."""

    def __init__(self, manifest: _Path, *, warm_up_s: Optional[float] = None) -> None:
        """The streamed import of the manifest at ``manifest`` (its streams are pushed,
        not read); the clock offset is estimated on the first ``warm_up_s`` seconds of the
        wheel stream (None: 300). Raises OdocalError for a manifest that is not streamed
        (naming why)."""
    @property
    def streams(self) -> dict[str, dict[str, Any]]:
        """Per stream: ``file``, ``time_column`` and the ``columns`` each message carries,
        in the order ``push_message`` takes its values."""
    def push_message(self, stream: str, t: float, values: Sequence[float]) -> None:
        """One message of ``stream``: time ``t`` in the stream's time unit (before its
        ``time_offset_s``) and the values of its columns. Raises OdocalError naming the
        stream (unknown, wrong number of values), the row and column (the import's checks),
        or ``values`` and its shape when it is not a 1-D sequence of numbers."""
    def push_messages(self, stream: str, t: _ArrayLike, values: _ArrayLike) -> None:
        """Several messages of ``stream``: times (n, 1-D) and values (n × columns, 2-D;
        converted to float64). Raises OdocalError naming the argument and its shape for
        another shape, or naming an argument of more than 50,000,000 messages before any
        is converted."""
    def end_stream(self, stream: str) -> None:
        """No more messages of ``stream`` come."""
    def finish(self) -> None:
        """Ends every stream and the drive: the last samples become ready, ``report`` is set."""
    def take_chunk(self, max: int = 400) -> Optional[dict[str, Any]]:
        """Up to ``max`` (at least 1) ready samples of one part, or None: ``part``, ``start``,
        ``starts_part``, ``reference_measured`` and ``samples`` (arrays ``t``, ``px``,
        ``py``, ``psi``, ``n_rl``, ``n_rr``, ``a_y``, ``beta``: ``Calibrator.push``'s arguments)."""
    @property
    def clock_offset(self) -> Optional[dict[str, Any]]:
        """The clock offset once the warm-up is over."""
    @property
    def report(self) -> Optional[dict[str, Any]]:
        """The import report after ``finish()``."""
    @property
    def held(self) -> int:
        """Rows and samples held now."""

class Calibrator:
    """The online calibrator (``odocal.online.Calibrator``): a recursive
    Gauss-Newton over the calibration segments of a stream of samples. A call from
    another thread while a push runs (without the GIL) waits for it."""

    def __init__(
        self,
        theta0: Optional[_ThetaLike] = None,
        sigma0: Optional[_SigmaLike] = None,
        sample_time_s: float = 0.025,
        *,
        gates: Optional[Mapping[str, Any]] = None,
        **options: Any,
    ) -> None:
        """``theta0`` (default: the paper's initial θ) with sd ``sigma0`` (default: the
        options' prior; a dict of ``c_e``, ``c_d``, ``t_r``, ``d`` or four numbers, each finite
        and not negative, as a history row's ``sigma``); ``options`` are the library's ``OnlineOptions`` fields
        (``information_scale``, ``random_walk={"c_e_relative": …}``, ``segments={…}``, …),
        ``gates`` the write-back gates' fields (``steady_s``, ``max_sigma_c_e_relative``, …).
        An unknown key raises TypeError naming the known ones; a bad value OdocalError."""
    def push(
        self,
        t: Optional[_ArrayLike],
        px: _ArrayLike,
        py: _ArrayLike,
        psi: _ArrayLike,
        n_rl: _ArrayLike,
        n_rr: _ArrayLike,
        a_y: _ArrayLike,
        beta: Optional[_ArrayLike] = None,
    ) -> None:
        """The next samples, in time order, as ``Drive.from_arrays`` takes them (``psi`` is
        unwrapped across chunks). With ``t``: each step the sample time (within 1 %) or a gap
        of more than 1.5 sample times, after which a new part starts. Raises OdocalError
        naming the argument and its shape for one that is not 1-D, and naming the column and
        the sample (its index in this push) for a value that is not finite or a time that
        does not fit, and naming an argument of more than 50,000,000 samples before any is
        converted (push in chunks); a refused push takes no sample."""
    def push_drive(self, drive: Drive, chunk: int = 400) -> None:
        """A whole drive as a new drive, in chunks."""
    def new_drive(self) -> None:
        """A new drive: the heading offset starts anew; θ and its covariance carry over."""
    def new_part(self) -> None:
        """A new continuous part of the current drive."""
    @property
    def theta(self) -> dict[str, float]: ...
    @property
    def sigma(self) -> dict[str, float]: ...
    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """5×5 covariance of ``[c_e, c_d, t_r, d, heading_offset]``."""
    @property
    def heading_offset(self) -> tuple[float, float]:
        """The drive's heading offset and its sd, rad."""
    @property
    def sample_time_s(self) -> float: ...
    @property
    def informative_time_s(self) -> float: ...
    @property
    def buffered_samples(self) -> int: ...
    @property
    def summary(self) -> dict[str, Any]:
        """``samples``, ``folded_segments``, ``validation_segments``,
        ``prequential_mean_position_error_m``, ``stored_mean_position_error_m``."""
    @property
    def recent_validation(self) -> list[dict[str, Any]]: ...
    @property
    def drive_estimate(self) -> Optional[dict[str, dict[str, float]]]:
        """θ from the current drive's folded segments alone, without the prior carried from
        earlier drives (what the write-back gates compare the estimate with):
        ``{"theta": {...}, "sigma": {...}}``, ``sigma`` scaled as ``Calibrator.sigma``;
        None until the drive determines every parameter."""
    @property
    def stored(self) -> Optional[dict[str, float]]:
        """The parameters in use (compared on each validation segment and by the gates)."""
    @stored.setter
    def stored(self, theta: Optional[_ThetaLike]) -> None: ...
    @property
    def gates(self) -> dict[str, Any]: ...
    def decide(self, stored: Optional[_ThetaLike] = None, calibrated: bool = True) -> dict[str, Any]:
        """The gates' decision: ``{"action": "write" | "hold" | "flag", "reasons", "theta", "sigma"}``.
        Raises OdocalError without ``stored`` when ``stored`` was never set."""

class History:
    """A vehicle's calibration history (SQLite); use ``odocal.History``."""

    def __init__(self, path: _Path) -> None: ...
    @property
    def path(self) -> PathLike[str]: ...
    @property
    def schema_version(self) -> int: ...
    def rows(self, vehicle: str) -> list[dict[str, Any]]: ...
    def latest(self, vehicle: str, *, usable_only: bool = True) -> Optional[dict[str, Any]]:
        """The row to start from: the most recent whose verdict is not ``rejected``
        and names no bias beyond its σ (``input_noise_bias``, ``heading_offset_held``),
        the row ``odocal follow`` starts from; or None. ``usable_only=False``: the
        most recent row whatever its verdict."""
    def drift(self, vehicle: str) -> list[dict[str, Any]]: ...
    def pooled(self, vehicle: str, ids: Optional[Sequence[int]] = None) -> Optional[dict[str, Any]]: ...
    def decisions(self, vehicle: str) -> list[dict[str, Any]]: ...
    def _record_report(self, report_json: str, vehicle: str, drive: Optional[Drive] = None) -> dict[str, Any]: ...
    def _record_dict(self, record: Mapping[str, Any]) -> dict[str, Any]: ...
