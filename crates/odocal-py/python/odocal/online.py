"""Online calibration: θ kept current while a drive streams in.

:class:`Calibrator` is the library's online calibrator (``odocal follow``
replays logs through it): a recursive Gauss-Newton over the calibration
segments of the stream, with θ and its σ at any time, the current drive's
reference heading offset as a state that starts anew with each drive, and
a random walk that lets θ drift. Memory does not grow with the stream.

>>> import odocal, odocal.online
>>> drive = odocal.simulate(seed=2, length_km=3.0, noise="off")
>>> cal = odocal.online.Calibrator(sample_time_s=drive.sample_time_s)
>>> a = drive.to_numpy()
>>> for i in range(0, len(drive), 400):
...     c = a[i:i + 400]
...     cal.push(c[:, 0], c[:, 1], c[:, 2], c[:, 3], c[:, 4], c[:, 5], c[:, 7], beta=c[:, 6])
>>> abs(cal.theta["c_e"] / drive.theta_true["c_e"] - 1) < 1e-3
True

Write-back: set ``cal.stored`` to the parameters in use; ``cal.decide()``
returns the gates' decision (``"write"``, ``"hold"`` or ``"flag"``, with
the reasons), as ``odocal follow`` logs it.

:class:`RawStream` turns a live system's raw messages (wheel ticks or
rates, pose, IMU, GNSS antennas, as a manifest describes its streams) into
canonical samples as they arrive: ``push_message(stream, t, values)`` in
time order per stream, ``take_chunk()`` for the samples ready (their
``"samples"`` are ``Calibrator.push``'s arguments), ``finish()`` at the end.
The clock offset is estimated on the first ``warm_up_s`` seconds (default
300) of the wheel stream; memory does not grow with the drive.
"""

from ._odocal import Calibrator, RawStream

__all__ = ["Calibrator", "RawStream"]
