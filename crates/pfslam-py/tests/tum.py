"""TUM text as `pfslam_io::tum::write_tum` prints it, to compare arrays with the CLI's files."""

import math
from typing import List

import numpy as np


def stamp_text(stamp_ns: int) -> str:
    """Seconds with 9 decimals, exactly (as `format_stamp_s`)."""
    sign = "-" if stamp_ns < 0 else ""
    s, ns = divmod(abs(stamp_ns), 1_000_000_000)
    return f"{sign}{s}.{ns:09d}"


def tum_lines(stamps_ns: np.ndarray, poses: np.ndarray) -> List[str]:
    """One line per pose: `stamp x y 0 0 0 qz qw` with the writer's decimals."""
    lines = []
    for stamp_ns, (_, x, y, yaw) in zip(stamps_ns.tolist(), poses.tolist()):
        half = 0.5 * yaw
        lines.append(
            f"{stamp_text(stamp_ns)} {x:.9f} {y:.9f} 0 0 0 {math.sin(half):.12f} {math.cos(half):.12f}"
        )
    return lines


def tum_body(text: str) -> List[str]:
    """The pose lines of a TUM text (comments left out)."""
    return [line for line in text.splitlines() if line and not line.startswith("#")]
