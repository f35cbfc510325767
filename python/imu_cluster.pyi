"""The IMU cluster's ground library (Rust crate ``host-test``) for Python: read, decode, allan, diagnose, simulate.

Conversion only: every function calls the library entry point the ``ground`` CLI calls. Errors of the library are
raised as :class:`Error` (a ``ValueError``) carrying the message the CLI prints.
"""

from os import PathLike
from typing import Any, Sequence, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, PathLike[str]]
_F64 = npt.NDArray[np.float64]

class Error(ValueError):
    """An error of the ground library (bad input, unreadable file), with the CLI's message."""

def read(path: _Path, calib: _Path | None = None) -> tuple[_F64, _F64, list[str]]:
    """Read a recording (interchange CSV, NumPy .npy, FPGA frame log, MIMU4444 stream).

    Returns ``(t, data, columns)``: times in s, a (samples x columns) array in deg/s and g, and the column names
    (``g00x`` ... ``a15z``, then ``temp_c`` when the recording has a temperature). ``calib``: a calibration table
    (.bin) for raw inputs. The loader's notes and warnings are issued as ``UserWarning``.
    """

def decode(path: _Path, csp_version: int = 1) -> dict[str, dict[str, Any]]:
    """Decode a telemetry stream (CSP packets in KISS frames) as ``ground decode`` does.

    Returns one dict of numpy arrays per message kind (``fused``, ``nav``, ``allan``, ``health``, ``housekeeping``,
    ``time``, ``faults``, ``ack``, ``pps``; nested fields joined with ``.``, ``null`` as NaN, enum variants as
    strings) and ``stats``: counts of what could not be decoded (``frames``, ``kiss_errors``, ``csp_errors``,
    ``other_port``, ``bad_messages``).
    """

def allan(
    x: npt.ArrayLike,
    rate: float,
    kind: str = "oadev",
    taus: str | Sequence[int] | None = "octave",
) -> dict[str, _F64]:
    """Allan-family deviation of frequency data ``x`` at ``rate`` Hz with noise id, EDF and 68.27 % intervals.

    ``kind``: ``"adev"``, ``"oadev"`` or ``"mdev"``. ``taus``: ``"octave"``, ``"decade"``, ``"all"``, a number of
    points per decade as text, or a list of averaging factors m. Returns arrays ``taus`` (s), ``m``, ``n``, ``dev``,
    ``ci_lo``, ``ci_hi``, ``edf``, ``alpha`` (NaN where the noise type is unknown).
    """

def diagnose(path_or_array: _Path | npt.ArrayLike, rate: float | None = None) -> dict[str, Any]:
    """Sim-to-real diagnosis of a static cluster recording: the dict ``ground diagnose --json`` writes.

    An array is (samples x columns) in group order (gx gy gz ax ay az per group, deg/s and g); it needs ``rate``.
    """

class Model:
    """The cluster model (the twin): the TOML file ``ground diagnose --model`` writes."""

    @staticmethod
    def load(path: _Path) -> Model:
        """Read a model file."""
    @staticmethod
    def fit(path_or_array: _Path | npt.ArrayLike, rate: float | None = None) -> Model:
        """Fit the model of a static recording, as ``ground diagnose --model`` does."""
    def save(self, path: _Path) -> None:
        """Write the model file."""
    def to_toml(self) -> str:
        """The model file's text."""
    @property
    def rate_hz(self) -> float:
        """Sample rate of the recording the model was fitted to, Hz."""
    @property
    def samples(self) -> int:
        """Samples of that recording."""

def simulate(
    model_or_preset: Model | str,
    samples: int | None = None,
    seconds: float | None = None,
    rate: float | None = None,
    seed: int = 1,
    without_effects: bool = False,
) -> _F64:
    """Simulate a cluster recording: a Model played or a preset (``"seed"``, ``"seed-fitted"``).

    Returns the (samples x columns) array :func:`read` gives for the CSV ``ground simulate`` writes.
    """
