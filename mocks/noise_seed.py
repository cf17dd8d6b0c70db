"""Noise seeds of the simulated devices, derived from what is measured rather than from when.

The simulated station (:mod:`mocks.station`) must give *the same data* when a
measurement is repeated: a profile re-taken at the same table angle after an
unplugged cable, a camera frame re-shot after a "busy" error.  So the seed of
every noise draw is a hash of the measurement's identity -- the station seed,
the placement number, the frame kind and the table angle (and, for the
frames of a burst shot at one view, the shot's number) -- instead of a
running counter.

The angle enters as :func:`angle_key`: reduced modulo 360 deg (the same view)
and rounded to 1e-6 deg, so angles that differ only by floating-point
round-off (an absolute move reached along another path) give the same key.
The hash is BLAKE2b (RFC 7693) of the parts' text, truncated to 63 bits, a
valid seed for :func:`numpy.random.default_rng`.

Examples
--------
>>> profile_seed(0, 1, 90.0) == profile_seed(0, 1, 450.0 + 1e-9)
True
>>> profile_seed(0, 1, 90.0) == profile_seed(0, 2, 90.0)
False
"""

from __future__ import annotations

import hashlib
import math

__all__ = ["angle_key", "stable_seed", "profile_seed", "frame_seed"]


def angle_key(angle_deg: float) -> str:
    """The table angle as a text key: modulo 360 deg, rounded to 1e-6 deg.

    Parameters
    ----------
    angle_deg
        Table angle (degrees, any real number).

    Returns
    -------
    str
        Six decimals in ``[0, 360)``; ``-0`` and ``360`` become ``0``.

    Raises
    ------
    ValueError
        ``angle_deg`` is not finite.

    Examples
    --------
    >>> angle_key(-90.0), angle_key(359.9999999), angle_key(12.3456789)
    ('270.000000', '0.000000', '12.345679')
    """
    a = float(angle_deg)
    if not math.isfinite(a):
        raise ValueError(f"angle_deg must be finite, got {angle_deg!r}")
    a = round(a % 360.0, 6)
    if a >= 360.0 or a == 0.0:
        a = 0.0
    return f"{a:.6f}"


def stable_seed(*parts: object) -> int:
    """A 63-bit seed from the text of ``parts`` (BLAKE2b), the same in every process and run.

    Examples
    --------
    >>> stable_seed("profile", 0, 1) == stable_seed("profile", 0, 1)
    True
    >>> 0 <= stable_seed("x") < 2**63
    True
    """
    text = "\x1f".join(str(p) for p in parts)
    digest = hashlib.blake2b(text.encode("utf-8"), digest_size=8).digest()
    return int.from_bytes(digest, "little") >> 1


def profile_seed(seed: int, placement: int, angle_deg: float) -> int:
    """Seed of the range noise of the profile at ``angle_deg`` in placement ``placement``.

    Examples
    --------
    >>> profile_seed(0, 1, 0.0) == profile_seed(0, 1, 360.0)
    True
    """
    return stable_seed("profile", int(seed), int(placement), angle_key(angle_deg))


def frame_seed(seed: int, placement: int, kind: str, angle_deg: float, shot: int = 0) -> int:
    """Seed of the sensor noise of a camera frame of ``kind`` (``"chart"``/``"object"``).

    ``shot`` numbers the frames of a burst at one view (0 = the first, or the only one): every shot
    is a new exposure with its own noise, and shot 0 keeps the seed a frame had before bursts
    existed, so a session without bursts renders byte for byte as before.

    Examples
    --------
    >>> frame_seed(0, 1, "chart", 0.0) == frame_seed(0, 1, "object", 0.0)
    False
    >>> frame_seed(0, 1, "object", 0.0, shot=0) == frame_seed(0, 1, "object", 0.0)
    True
    >>> frame_seed(0, 1, "object", 0.0, shot=1) == frame_seed(0, 1, "object", 0.0)
    False
    """
    shot = int(shot)
    if shot < 0:
        raise ValueError(f"shot must be >= 0 (the frame's number in its burst), got {shot}")
    if shot == 0:
        return stable_seed("frame", int(seed), int(placement), str(kind), angle_key(angle_deg))
    return stable_seed("frame", int(seed), int(placement), str(kind), angle_key(angle_deg), f"shot/{shot}")
