"""Segment inertial parameters after de Leva (1996), "Adjustments to Zatsiorsky-Seluyanov's segment inertia
parameters", J. Biomechanics 29(9), table 4 (male values).

Each entry: mass fraction of total body mass, centre of mass as a fraction of the segment length from its
proximal end, and radii of gyration as fractions of segment length about the sagittal (front-back), transverse
(left-right) and longitudinal axes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SegmentInertia:
    mass_fraction: float
    com_fraction: float
    gyration_sagittal: float
    gyration_transverse: float
    gyration_longitudinal: float


DE_LEVA_MALE: dict[str, SegmentInertia] = {
    "head": SegmentInertia(0.0694, 0.5002, 0.303, 0.315, 0.261),  # head + neck, from vertex
    "upper_trunk": SegmentInertia(0.1596, 0.2999, 0.716, 0.454, 0.659),  # from cervicale
    "middle_trunk": SegmentInertia(0.1633, 0.4502, 0.482, 0.383, 0.468),  # from xiphoid
    "lower_trunk": SegmentInertia(0.1117, 0.6115, 0.615, 0.551, 0.587),  # from omphalion
    "upper_arm": SegmentInertia(0.0271, 0.5772, 0.285, 0.269, 0.158),
    "forearm": SegmentInertia(0.0162, 0.4574, 0.276, 0.265, 0.121),
    "hand": SegmentInertia(0.0061, 0.7900, 0.628, 0.513, 0.401),
    "thigh": SegmentInertia(0.1416, 0.4095, 0.329, 0.329, 0.149),
    "shank": SegmentInertia(0.0433, 0.4459, 0.255, 0.249, 0.103),
    "foot": SegmentInertia(0.0137, 0.4415, 0.257, 0.245, 0.124),
}
