"""odocal: wheel-odometry model calibration, numpy in, plain Python objects out.

odocal calibrates a vehicle's wheel-odometry model θ = [c_e, c_d, t_r, d]
(effective rear wheel circumference, circumference difference, rear track
width, load-transfer coefficient) from a logged drive: by default with an
errors-in-variables filter that models the noise on the wheel inputs, or by
the 3-step method of Fazekas, Gáspár and Németh (IFAC-PapersOnLine 2022),
or raw batch Gauss-Newton. This package is a thin layer over the Rust library that the
``odocal`` command-line tool also uses: the same checks, the same numbers,
the same JSON report.

>>> import odocal
>>> drive = odocal.simulate(seed=1, length_km=3.0)
>>> report = odocal.calibrate(drive, method="batch-gn")
>>> sorted(report.theta)
['c_d', 'c_e', 'd', 't_r']

Numeric work runs with the GIL released, so other Python threads keep
running; a ``progress`` callback is only ever called on the calling thread.
An ``online.Calibrator`` or ``online.RawStream`` used from another thread
while it pushes waits for the push to end.
"""

from __future__ import annotations

import json
import os
from typing import Any, Callable, Mapping, Optional, Sequence, Union

import numpy as np

from . import _odocal
from ._odocal import COLUMNS, Drive, OdocalError, __version__, read_params, simulate
from ._odocal import History as _History
from . import online

__all__ = [
    "CALIBRATE_OPTIONS",
    "COLUMNS",
    "THETA_NAMES",
    "CalibrationReport",
    "Drive",
    "History",
    "OdocalError",
    "calibrate",
    "online",
    "read_params",
    "simulate",
    "validate",
    "__version__",
]

#: The parameter names, in vector order.
THETA_NAMES = ("c_e", "c_d", "t_r", "d")

#: The keyword options :func:`calibrate` takes: the library's calibration
#: settings (``method`` among them), then ``holdout``, ``validate_on`` and
#: ``carry_heading_offset``; e.g. to check a command line's options before
#: a long run.
CALIBRATE_OPTIONS: tuple = _odocal.CALIBRATE_OPTIONS

ThetaLike = Union[Mapping[str, float], Sequence[float], str, "os.PathLike[str]", "CalibrationReport"]
ProgressCallback = Callable[[str, int, int], Any]


class CalibrationReport:
    """The result of :func:`calibrate`: the library's report as plain Python objects.

    ``to_dict()`` / ``to_json()`` are exactly what ``odocal calibrate --json``
    writes for the same drive and options (``timing_s`` aside, which is wall
    time). The properties below are shortcuts into that dict.
    """

    __slots__ = ("_dict", "_json", "_drive", "_scored_on")

    def __init__(self, report: dict, text: str, drive: Optional[Drive] = None,
                 scored_on: Optional[dict] = None) -> None:
        self._dict = report
        self._json = text
        self._drive = drive
        self._scored_on = scored_on or {}

    # -- the whole report -------------------------------------------------
    def to_dict(self) -> dict:
        """The full report as nested dicts and lists (a deep copy)."""
        return json.loads(self._json)

    def to_json(self) -> str:
        """The full report as the CLI's pretty JSON text."""
        return self._json

    # -- shortcuts ----------------------------------------------------------
    @property
    def method(self) -> str:
        """The method run: ``"eiv"``, ``"three-step"`` or ``"batch-gn"``."""
        return self._dict["method"]

    @property
    def theta(self) -> dict:
        """The calibrated θ: ``{"c_e": m, "c_d": m, "t_r": m, "d": m per m/s²}``."""
        return dict(self._dict["theta"])

    @property
    def theta_array(self) -> np.ndarray:
        """The calibrated θ as a float64 array ``[c_e, c_d, t_r, d]``."""
        return np.array([self._dict["theta"][k] for k in THETA_NAMES], dtype=np.float64)

    @property
    def covariance(self) -> np.ndarray:
        """The 4×4 model covariance ``σ²(JᵀWJ)⁻¹`` of θ (zero rows for fixed parameters)."""
        cov = self._dict.get("covariance")
        if cov is None:  # a report without a top-level covariance holds it under identification
            cov = self._dict["identification"]["covariance"]
        return np.array(cov, dtype=np.float64)

    @property
    def sigma(self) -> dict:
        """The 1σ that stands for the result, same keys as ``theta`` (``None``
        for a held parameter): the CLI's JSON ``sigma``, the σ of the verdict,
        the text report, the HTML report and ``--params-out``. Its source is in
        :attr:`result_sigma`; the model σ in :attr:`model_sigma`."""
        s = self._dict.get("sigma")
        if s is None:  # reports without a result σ: the model σ
            return self.model_sigma
        return {k: s.get(k) for k in THETA_NAMES}

    @property
    def model_sigma(self) -> dict:
        """The model 1σ of each parameter (square root of the diagonal of
        :attr:`covariance`), same keys as ``theta``; ``None`` for a parameter
        the method did not estimate (its covariance row is zero: held, or
        kept at the default method's batch Gauss-Newton start; the text
        report's ``held`` or ``–``). It assumes white residuals and
        understates the uncertainty under input noise."""
        c = self.covariance
        return {k: float(np.sqrt(c[i, i])) if c[i, i] > 0 else None for i, k in enumerate(THETA_NAMES)}

    @property
    def result_sigma(self) -> Optional[dict]:
        """The 1σ that stands for the result with its source, as the verdict,
        the CLI's JSON and ``--params-out`` give it: the σ for the next drive
        (within-drive ⊕ between-drive), ``{"source": "cluster-robust" |
        "batch-spread" | "model", "covers": "next-drive", "c_e": …, "c_d": …,
        "t_r": …, "d": …}`` (``None`` for a held parameter; ``source`` names
        the covariance of its within-drive part). :attr:`sigma` is the same
        without the source; :attr:`model_sigma` and :attr:`within_drive_sigma`
        are the narrower σ. ``None`` for reports without it."""
        s = self._dict.get("sigma")
        return dict(s) if s is not None else None

    @property
    def within_drive_sigma(self) -> Optional[dict]:
        """The method's within-drive 1σ (how well this drive determines θ, not
        how far the next drive's θ lies), same keys as :attr:`result_sigma`
        with ``"covers": "within-drive"``. ``None`` for reports without it."""
        s = self._dict.get("sigma_within_drive")
        return dict(s) if s is not None else None

    @property
    def validation(self) -> dict:
        """Ē_p of the result: ``{"mean_position_error_m", "segments", "held_out"}``."""
        return dict(self._dict["validation"])

    @property
    def mean_position_error_m(self) -> float:
        """Ē_p of the calibrated θ on the validation segments, m."""
        return float(self._dict["validation"]["mean_position_error_m"])

    @property
    def initial(self) -> dict:
        """θ_0 and its Ē_p: ``{"theta": {...}, "mean_position_error_m": m}``."""
        return dict(self._dict["initial"])

    @property
    def verdict(self) -> Optional[Any]:
        """The library's verdict on the result, when the report carries one (else None)."""
        return self._dict.get("verdict")

    @property
    def warnings(self) -> list:
        """Things the user should know (unobservable parameters, dropped segments)."""
        return list(self._dict.get("warnings", []))

    @property
    def truth(self) -> Optional[dict]:
        """For a simulated drive: the true θ and its Ē_p (as the CLI reports), else None."""
        return self._dict.get("truth")

    @property
    def method_details(self) -> str:
        """The method's own account of the fit, as ``odocal calibrate`` prints
        it: for EIV the filter's windows, iterations and termination, the noise
        model at the start and as estimated (physical units), the σ widening
        for the estimated noise levels and whether the result is the EIV
        estimate or the batch G-N fallback; for batch-gn the fit (segments,
        iterations, termination, rcond) and which σ stands beside the model σ;
        for the 3-step method also its steps 1 and 2 (batch runs, QP jobs)."""
        return _odocal._method_details(self._json)

    def to_html(self, path: Union[str, "os.PathLike[str]"], title: Optional[str] = None) -> None:
        """Writes the self-contained HTML report (verdict, θ table, Ē_p, map,
        per-segment errors, step-1 spread, residuals, warnings, method
        details) to ``path``.

        Needs the drive the report was made from (reports from
        :func:`calibrate` keep it); ``title`` defaults to "odocal calibration".
        """
        if self._drive is None:
            raise OdocalError("this report has no drive to draw (make it with odocal.calibrate)")
        _odocal._report_html(
            self._drive, self._json, os.fspath(path), title=title, drives=self._input_drives(), **self._scored_on
        )

    def _input_drives(self) -> list:
        """The drives the report was made from (calibration and ``validate_on``), one by one."""
        out: list = []
        for d in (self._drive, self._scored_on.get("validate_on")):
            if isinstance(d, Drive):
                out.append(d)
            elif d is not None:
                out.extend(d)
        return out

    def _calibration_drives(self) -> list:
        """The calibration drives, one by one (none for a report without them)."""
        d = self._drive
        if d is None:
            return []
        return [d] if isinstance(d, Drive) else list(d)

    def write_params(
        self,
        path: Union[str, "os.PathLike[str]"],
        *,
        input: Optional[str] = None,
        node: str = "odocal",
        mapping: str = "odocal",
    ) -> None:
        """Writes the parameter file ``odocal calibrate --params-out`` writes:
        a ROS 2 parameter file for ``.yaml``/``.yml`` (``ros__parameters``
        under ``node``, a ROS 2 node name as ``--params-node`` takes it:
        letters, digits and ``_``, ``/`` for a namespace), JSON for
        ``.json``; θ with the σ that stands for the result (``result_sigma``;
        ``<name>_held: true`` for held ones), the reference extrinsics, the
        verdict and provenance: ``input`` names the calibration drives (by
        default each drive's file, as the CLI's; ``"simulated drive"`` for
        one of :func:`simulate`, ``"python"`` for one made from arrays;
        comma separated), ``fingerprint`` their :attr:`Drive.fingerprint`,
        ``wheel_scale`` (drives from manifests) what c_e, c_d and d are per.
        ``mapping="diff_drive_controller"`` adds that controller's keys.
        :func:`read_params` and every θ argument read it back. The file is
        written atomically; a node that is no ROS 2 node name, or a path
        that is a file of the report's drives (a CSV, manifest, stream file
        or sidecar), raises :class:`OdocalError` and writes nothing."""
        _odocal._write_params(
            self._json,
            os.fspath(path),
            input=input,
            node=node,
            mapping=mapping,
            drives=self._input_drives(),
            calibration=self._calibration_drives(),
        )

    def __repr__(self) -> str:
        t = self._dict["theta"]
        return (
            f"<odocal.CalibrationReport {self.method}: c_e={t['c_e']:.6f} m, c_d={t['c_d'] * 1e3:.4f} mm, "
            f"t_r={t['t_r']:.6f} m, d={t['d'] * 1e3:.4f} mm/(m/s²); "
            f"Ē_p {self.mean_position_error_m:.3f} m>"
        )


class History(_History):
    """A vehicle's calibration history: the SQLite file that ``odocal
    calibrate --vehicle ID --db FILE`` and ``odocal follow`` write.

    ``History(path)`` opens it (creating it when missing; several processes
    may read and write it at once). ``rows(vehicle)``: the table
    ``calibrations`` as a list of dicts; ``drift(vehicle)``: changes between
    consecutive rows beyond three combined σ; ``pooled(vehicle, ids=None)``:
    the inverse-variance mean with the between-drive sd. Both count each
    drive once, by its most recent row (a drive calibrated by several
    methods has a row for each), and leave out rows whose verdict is
    ``rejected`` and each parameter a row held or found not observable
    (``held``, ``unobservable``); ``pooled`` leaves out the ``online`` rows
    of ``follow`` too (running estimates, each holding the drives before
    it) and names the rows set aside, rejected and online;
    ``decisions(vehicle)``: the write-back decisions of ``odocal follow``;
    ``latest(vehicle, usable_only=True)``: the row to start from, the one
    ``odocal follow`` starts from (the most recent whose verdict is not
    ``rejected`` and names no bias beyond its σ, ``input_noise_bias`` or
    ``heading_offset_held``), or with ``usable_only=False`` the most recent
    row whatever its verdict. Errors raise :class:`OdocalError`.
    """

    def record(
        self,
        report: Union["CalibrationReport", Mapping[str, Any]],
        *,
        vehicle: Optional[str] = None,
        drive: Optional[Drive] = None,
    ) -> dict:
        """Records a calibration for ``vehicle``, unless its history already
        holds the same drive (fingerprint) calibrated by the same method.

        ``report`` is a :class:`CalibrationReport` (θ, its σ, verdict,
        method, the verdict's reason kinds and the calibration drives'
        fingerprints and files with the files' source digest, as
        ``odocal calibrate --vehicle --db`` records them; the time span from
        the report's drive) or a dict of the table's fields (``vehicle``,
        ``fingerprint``, ``method``, ``theta``; optional ``sigma``,
        ``held``, ``unobservable``, ``sources``, ``source_digest`` (a hash
        of the drive's files: ``odocal follow`` skips a drive whose files
        and time a row holds, however it was imported), ``t_start_s``,
        ``t_end_s``, ``heading_offset_rad``, ``verdict``,
        ``sigma_model_only``, ``reasons`` (a list of verdict reason kinds);
        another key raises :class:`OdocalError`
        naming it; ``theta`` a dict of ``c_e``, ``c_d``, ``t_r``, ``d`` or
        four numbers, ``sigma`` the same with ``None`` for a parameter
        without σ). Returns ``{"id": row id, "new": False when it was
        already recorded}``.

        The library checks every record before writing it, as ``odocal
        calibrate --vehicle`` does: the vehicle not blank, without a space
        at either end or a control character; the method one of ``eiv``,
        ``three-step``, ``batch-gn``, ``online``; θ within the physical
        limits of every θ argument; σ finite and not negative; ``held`` and
        ``unobservable`` naming parameters of θ. A record that fails raises
        :class:`OdocalError` and writes nothing.
        """
        if isinstance(report, CalibrationReport):
            if vehicle is None:
                raise TypeError("record(report): give vehicle=")
            d = drive if drive is not None else report._drive
            if not isinstance(d, Drive):
                d = None
            return self._record_report(report._json, vehicle, d)
        rec = dict(report)
        if vehicle is not None:
            rec["vehicle"] = vehicle
        return self._record_dict(rec)


_PARAM_FILE_SUFFIXES = (".yaml", ".yml", ".json")


def _theta_arg(theta: ThetaLike) -> Any:
    """θ as the native module reads it; a path object that names no
    parameter file, or an array that is not four numbers in one dimension,
    raises :class:`OdocalError` saying what θ takes."""
    if isinstance(theta, CalibrationReport):
        return theta.theta
    if isinstance(theta, os.PathLike):
        path = os.fspath(theta)
        if not str(path).lower().endswith(_PARAM_FILE_SUFFIXES):
            raise OdocalError(
                f"θ: {path} is not a parameter file: give the .yaml, .yml or .json file that "
                "write_params (--params-out) writes, or θ as numbers"
            )
        return path
    if isinstance(theta, np.ndarray):
        if theta.ndim != 1:
            raise OdocalError(
                f"θ: got an array of shape {theta.shape}, where four numbers c_e, c_d, t_r, d "
                "(a 1-D array) are expected"
            )
        return theta.tolist()
    return theta


def calibrate(
    drive: Union[Drive, Sequence[Drive]],
    method: Optional[str] = None,
    *,
    progress: Optional[ProgressCallback] = None,
    threads: Optional[int] = None,
    **options: Any,
) -> CalibrationReport:
    """Calibrates θ on ``drive`` and returns a :class:`CalibrationReport`.

    ``drive`` is one :class:`Drive` or a list of drives of one vehicle,
    fitted jointly (as ``odocal calibrate A B``: segments never span two
    drives; their sample times must agree; a list has no single true θ).
    The drives share θ and the lever arm; when the heading offset is
    estimated (the default method does) each drive gets its own: the
    report's ``heading_offset_per_drive`` lists them (``source``,
    ``fingerprint``, ``value``, ``sigma`` in rad) and
    ``extrinsics.value.heading_offset`` is their mean.

    ``method`` is ``"eiv"`` (the default, unless the drive's manifest states
    another: the errors-in-variables filter over the whole drive, started
    from batch G-N on all segments, falling back to it when its consistency
    checks fail), ``"three-step"`` (the paper's method, with input
    compensation) or ``"batch-gn"`` (raw batch Gauss-Newton over all
    selected segments).

    Options are keyword arguments, the library's calibration settings
    (``odocal::calibrate::settings::Settings``): named like the keys of a
    manifest's ``[calibration]`` and, in kebab case, the CLI's flags
    (``--min-yaw-rate`` is ``min_yaw_rate=``); None means the default:

    - ``theta0``: initial guess (dict of ``c_e``, ``c_d``, ``t_r``, ``d``,
      4 numbers, ``"c_e,c_d,t_r,d"``, a parameter file or a
      :class:`CalibrationReport`, whose θ it takes);
    - ``fix``: parameters held at θ_0 (list of names or ``"c_d,t_r,d"``);
    - ``segment_length``, ``segment_stride``, ``validation_length`` (samples);
    - ``min_yaw_rate`` (rad/s): peak yaw rate for a segment to be selected,
      and ``keep_one_way`` (bool, False): keep the turning-only selection
      when every selected segment turns one way (as ``--keep-one-way``; by
      default the straight segments are added, with a warning): methods
      ``"batch-gn"`` and ``"three-step"`` only (``"eiv"`` fits every
      segment);
    - ``seed`` (int 0 … 2^64 − 1, 0): seed of the random batches and segments,
      ``qp_solver`` (``"structured"`` | ``"clarabel"``), ``batches``,
      ``batch_size``, ``picks`` (step 1), ``final_segments`` (``"all"`` or a
      number of random segments): method ``"three-step"`` only;
    - ``max_iterations``: Gauss-Newton iterations;
    - ``holdout`` (``"first-half"`` | ``"second-half"``: the half held out
      for validation) or ``validate_on`` (another :class:`Drive`, or a list
      of them: Ē_p over all of them, and per drive in the report's
      ``"validate_on"``, named ``validate_on[i]``; each at the sample rate
      of ``drive``, as validation segments are counted in samples, else
      :class:`OdocalError`). The drives, and the
      ``validate_on`` drives, must count wheel revolutions alike (their
      manifests' ``[wheels]`` scale, e.g. ``ticks_per_rev``: c_e, c_d and d
      are per model revolution); others raise :class:`OdocalError`;
    - ``auto_fix`` (bool): hold the parameters the data cannot determine;
    - ``estimate`` (``"lever-arm,heading-offset"`` or a list),
      ``lever_arm`` (``[x, y]``, m), ``heading_offset`` (rad): the reference
      sensor's extrinsics, as ``--estimate``, ``--lever-arm``,
      ``--heading-offset``;
    - ``noise_model`` (path of a noise-model TOML, or a dict of its fields), ``known_noise`` (noise
      sources whose level in the starting model is known and held, a list
      or ``"heading_white,pose_white"``, as ``--known-noise``), ``fix_noise``,
      ``fallback``, ``eiv_window``, ``quantisation`` (``"process"`` |
      ``"measurement"`` | ``"counting"``), ``quantisation_level``
      (``"scaled"`` | ``"given"`` | ``"from-readings"``), ``heading_noise``
      (``"tied"`` | ``"separate"``), ``lateral_noise`` (``"tied"`` |
      ``"stated"``), ``correct_bias`` (B, an even number: replicates of the
      bias correction that is on by default with B = 4 — the estimator's own
      bias, estimated by a bootstrap in antithetic pairs, subtracted from
      c_e and c_d, as ``--correct-bias``; ``0`` turns it off, as
      ``--no-bias-correction``), ``correct_bias_of`` (the parameters it
      corrects, ``"c_e,t_r"`` or a list; default c_e and c_d, as
      ``--correct-bias-of``), ``bootstrap`` (B: a parametric bootstrap's intervals and
      bias in the report) with ``bootstrap_seed`` (their seed): method
      ``"eiv"`` only, as the CLI's flags.

    A drive read from a manifest carries the manifest's ``[noise]``,
    ``[reference]`` and ``[calibration]`` settings (``drive.import_report``); they apply unless
    the matching keyword is given (a key of a method other than the one
    used is ignored, saying so), and the report says what became of each
    (``"manifest_settings"``) and which noise model method ``"eiv"`` started
    from (``"noise_model_origin"``), as the CLI's JSON does.

    A keyword the method does not use is an error naming it and the
    methods that use it.

    ``threads`` runs the calibration on that many threads (default: all
    cores); the result does not depend on it. ``progress(stage, done,
    total)`` is called on the calling thread, with the GIL, at most about
    ten times a second. An exception it raises (or Ctrl-C) is re-raised once
    the calibration has finished.

    The report's ``"drives"`` lists each drive's role (``"calibration"``,
    ``"validation"``), the file it was read from and its
    :attr:`Drive.fingerprint`. The same drive given twice (in ``drive``, or
    as a ``validate_on`` copy of a calibration drive) raises
    :class:`OdocalError` naming both, and so does a drive that shares more
    than 1 % of its samples with another (a part of it, or a copy thinned
    to every n-th sample), naming the fraction.

    Raises :class:`OdocalError` (a ``ValueError``) with the library's
    message naming the option for bad options, or for data the method cannot
    use; ``TypeError`` for an unknown option, naming the known ones
    (:data:`CALIBRATE_OPTIONS`).
    """
    if options.get("theta0") is not None:
        options["theta0"] = _theta_arg(options["theta0"])
    report, text = _odocal.calibrate(drive, method, progress=progress, threads=threads, **options)
    scored_on = {k: options[k] for k in ("holdout", "validate_on") if options.get(k) is not None}
    return CalibrationReport(report, text, drive, scored_on)


def validate(
    drive: Drive,
    theta: ThetaLike,
    *,
    validation_length: Optional[int] = None,
    threads: Optional[int] = None,
    carry_heading_offset: bool = False,
    params_node: Optional[str] = None,
    fit_drive: bool = True,
) -> dict:
    """Mean position error Ē_p of ``theta`` by dead reckoning on the validation segments of ``drive``.

    Returns the CLI's ``validate --json``: ``{"theta", "mean_position_error_m",
    "segments", "per_segment_m", "schema_version"}``. ``theta`` is a dict, four numbers, the
    text ``"c_e,c_d,t_r,d"``, a :class:`CalibrationReport` or the path of a parameter file
    (``.yaml``, ``.yml``, ``.json``, as :meth:`CalibrationReport.write_params` and
    ``--params-out`` write it). With a report or a file, the reference extrinsics its
    calibration estimated are used too (held ones give way to the drive's manifest
    ``[reference]``), as ``odocal validate --theta FILE`` does. The heading offset is the
    reference's per-drive bias: this drive's own is re-estimated with θ and the lever arm
    held where the calibration estimated one or ``theta`` is numbers, starting from the
    calibration's estimate, else the drive's manifest value, else 0 (``heading_offset_fit``: ``value``, ``calibration`` — the start —,
    ``std_dev`` in rad — cluster-robust when ``robust`` —, ``segments``) unless
    ``carry_heading_offset=True``, which holds that start. On a drive the report's or the
    file's calibration ran on (the same drive fingerprint) the calibration's own heading offset
    for that drive is held instead (``calibration_drive``: ``True``), so Ē_p is the
    calibration's own.
    ``params_node`` names the node of a parameter file that holds several nodes'
    parameters (such a file is refused without it). A ``UserWarning`` says when the
    report's or the file's wheel scale (what c_e, c_d and d are per) is not the drive's.

    The verdict, ``drive_fit``: θ fitted on this drive by batch Gauss-Newton started from
    ``theta`` and from the paper's θ_0, the better of the two, or by the default method from
    θ_0 when batch Gauss-Newton's fit fails, is worse than ``theta`` or held parameters the
    drive does not determine, and the default's is
    better (``theta``, ``heading_offset_rad`` when re-estimated, ``method``,
    ``batch_gn_failure`` when the default method fitted it, ``mean_position_error_m``),
    ``ratio`` (Ē_p of ``theta`` over the fit's) and ``fits`` (the ratio is at most 1.6): a
    ``theta`` that does not fit points at a changed vehicle, another vehicle's parameters or
    inputs that differ from the calibration's. ``drive_fit_error`` says why a drive has no
    verdict (no plausible fit, or one far worse than ``theta``); ``fit_drive=False`` skips it.
    """
    report_json = theta._json if isinstance(theta, CalibrationReport) else None
    return _odocal.validate(
        drive,
        _theta_arg(theta),
        validation_length=validation_length,
        threads=threads,
        report_json=report_json,
        carry_heading_offset=carry_heading_offset,
        params_node=params_node,
        fit_drive=fit_drive,
    )
