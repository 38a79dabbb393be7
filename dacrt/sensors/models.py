"""The named beam patterns of spinning lidars: each model's nominal vertical angles, lowest first,
and where its maker publishes them (docs/sensors.md, "Lidar").

A unit's own calibration (Velodyne's db.xml / XML calibration, Ouster's ``beam_altitude_angles``)
differs from these by fractions of a degree and can be given as explicit elevations instead.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class BeamModel:
    """The nominal vertical angles of a sensor, lowest first, and where they are published."""

    name: str
    vertical_angles_deg: tuple[float, ...]
    source: str


def _uniform(low: float, high: float, n: int) -> tuple[float, ...]:
    """n angles from low to high, evenly spaced: low + (high - low) * k / (n - 1)."""
    return tuple(low + (high - low) * k / (n - 1) for k in range(n))


# Velodyne VLP-16 ("Puck"): 16 lasers from -15 to +15 degrees, 2 degrees apart.
# Source: Velodyne LiDAR, "VLP-16 User Manual" (63-9243), table "Laser ID and vertical angle"
# (-15, 1, -13, 3, ... by laser ID), and the VLP-16 data sheet: vertical field of view 30 degrees
# (+15 to -15), vertical resolution 2.0 degrees.
VLP_16 = BeamModel(
    "VLP-16",
    tuple(float(a) for a in range(-15, 16, 2)),
    "Velodyne VLP-16 User Manual (63-9243), laser ID / vertical angle table; "
    "VLP-16 data sheet: +15 to -15 degrees, 2.0 degree resolution",
)

# Velodyne HDL-32E: 32 lasers from -30.67 to +10.67 degrees, 4/3 degree apart.
# Source: Velodyne LiDAR, "HDL-32E User's Manual" (63-9113), table of vertical angles by laser
# ID (-30.67, -9.33, -29.33, -8.00, ... as printed, to two decimals), and the HDL-32E data sheet:
# vertical field of view +10.67 to -30.67 degrees.
HDL_32E = BeamModel(
    "HDL-32E",
    (
        -30.67,
        -29.33,
        -28.00,
        -26.67,
        -25.33,
        -24.00,
        -22.67,
        -21.33,
        -20.00,
        -18.67,
        -17.33,
        -16.00,
        -14.67,
        -13.33,
        -12.00,
        -10.67,
        -9.33,
        -8.00,
        -6.67,
        -5.33,
        -4.00,
        -2.67,
        -1.33,
        0.00,
        1.33,
        2.67,
        4.00,
        5.33,
        6.67,
        8.00,
        9.33,
        10.67,
    ),  # fmt: skip
    "Velodyne HDL-32E User's Manual (63-9113), vertical angle by laser ID; "
    "HDL-32E data sheet: +10.67 to -30.67 degrees",
)

# Velodyne HDL-64E (S2, S3): an upper block of 32 lasers from +2 to -8.33 degrees at 1/3 degree
# spacing and a lower block of 32 lasers from -8.83 to -24.33 degrees at 1/2 degree spacing.
# Source: Velodyne LiDAR, "HDL-64E S3 User's Manual and Programming Guide" (63-HDL64ES3), laser
# and detector arrangement (the S2 manual's appendix "Angular Resolution" gives the same blocks);
# the data sheet states a vertical field of view of about 26.9 degrees (+2 to -24.9) in 64
# subdivisions of about 0.4 degrees. Each unit's db.xml holds its calibrated angles.
HDL_64E = BeamModel(
    "HDL-64E",
    tuple(sorted([2 - k / 3 for k in range(32)] + [-53 / 6 - k / 2 for k in range(32)])),
    "Velodyne HDL-64E S3 User's Manual and Programming Guide (63-HDL64ES3): upper block +2 to "
    "-8.33 degrees at 1/3 degree, lower block -8.83 to -24.33 degrees at 1/2 degree",
)

# Ouster OS1 (Rev 6 and later), uniform beam spacing: 64 or 128 beams spread evenly over a
# vertical field of view of 45 degrees (+22.5 to -22.5).
# Source: Ouster, "OS1 Mid-Range High-Resolution Imaging Lidar" data sheet: vertical field of view
# 45 degrees (+22.5 to -22.5), uniform beam spacing, 32/64/128 channels. (The first-generation
# OS1-64 data sheet gave +16.6 to -16.6 degrees; send such a unit's beam_altitude_angles, from
# its metadata, as vertical_angles_deg.)
OS1_64 = BeamModel(
    "OS1-64",
    _uniform(-22.5, 22.5, 64),
    "Ouster OS1 data sheet (Rev 6 and later): 45 degree vertical field of view (+22.5 to -22.5), "
    "uniform beam spacing, 64 channels",
)
OS1_128 = BeamModel(
    "OS1-128",
    _uniform(-22.5, 22.5, 128),
    "Ouster OS1 data sheet (Rev 6 and later): 45 degree vertical field of view (+22.5 to -22.5), "
    "uniform beam spacing, 128 channels",
)

#: The named beam patterns of ``"model"``, by name.
MODELS: dict[str, BeamModel] = {m.name: m for m in (VLP_16, HDL_32E, HDL_64E, OS1_64, OS1_128)}
