"""Plot foot heights, speeds and the automatic contact labels of motion capture clips, to check the label rule.

For each clip: one panel per contact site with its height above the floor and its speed, the Rempe 3.2 labels
(`physmocap.contacts.labels`, shaded) and, for comparison, PhysCap 4.2's rule (speed under 5 cm/s and height
under the first ten frames' mean height + 5 cm, a tick row); a last panel with the root speed and the stationary
flag. Usage:

    .venv/bin/python scripts/plot_contact_labels.py OUT_DIR CLIP.bvh [CLIP.bvh ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from physmocap.contacts.labels import (  # noqa: E402
    CONTACT_SITE_INDICES, CONTACT_SITES, LabelSettings, motion_labels, point_speed,
)
from physmocap.mocap.bvh_reader import load_mocap  # noqa: E402

PHYSCAP_MAX_SPEED = 0.05  # m/s
PHYSCAP_HEIGHT_MARGIN = 0.05  # m above the mean height of the first ten frames


def plot_clip(path: Path, out_dir: Path, settings: LabelSettings = LabelSettings()) -> Path:
    clip = load_mocap(path)
    contacts, stationary = motion_labels(clip.positions, clip.fps, settings)
    sites = clip.positions[:, CONTACT_SITE_INDICES]
    speed = point_speed(sites, clip.fps, settings.contact_speed_interval, centred=False)
    physcap = (speed < PHYSCAP_MAX_SPEED) & (sites[..., 2] < sites[:10, :, 2].mean(axis=0) + PHYSCAP_HEIGHT_MARGIN)
    root_speed = point_speed(clip.joint("pelvis"), clip.fps, settings.stationary_speed_interval, centred=True)
    time = np.arange(clip.num_frames) / clip.fps

    figure, axes = plt.subplots(5, 1, figsize=(12, 11), sharex=True)
    for column, (axis, name) in enumerate(zip(axes, CONTACT_SITES)):
        axis.fill_between(time, 0, 1, where=contacts[:, column], transform=axis.get_xaxis_transform(),
                          color="tab:green", alpha=0.25, label="contact (Rempe 3.2)")
        axis.plot(time, 100 * sites[:, column, 2], color="tab:blue", label="height (cm)")
        axis.axhline(100 * settings.contact_max_height, color="tab:blue", ls=":", lw=0.8)
        axis.set_ylim(-5, 40)
        axis.set_ylabel(f"{name}\nheight cm")
        speed_axis = axis.twinx()
        speed_axis.plot(time, speed[:, column], color="tab:red", lw=0.8, label="speed (m/s)")
        speed_axis.axhline(settings.contact_max_speed, color="tab:red", ls=":", lw=0.8)
        speed_axis.set_ylim(0, 4)
        speed_axis.set_ylabel("speed m/s")
        marks = np.where(physcap[:, column])[0]
        axis.plot(time[marks], np.full(len(marks), 37.0), "|", color="black", ms=6, label="PhysCap 4.2 rule")
        if column == 0:
            handles = axis.get_legend_handles_labels()[0] + speed_axis.get_legend_handles_labels()[0]
            axis.legend(handles=handles, loc="upper right", fontsize=7, ncol=4)
    axes[4].fill_between(time, 0, 1, where=stationary, transform=axes[4].get_xaxis_transform(), color="tab:gray",
                         alpha=0.3, label="stationary")
    axes[4].plot(time, root_speed, color="black", label="root speed (m/s)")
    axes[4].axhline(settings.stationary_max_speed, color="black", ls=":", lw=0.8)
    axes[4].set_ylim(0, 3)
    axes[4].set_ylabel("root m/s")
    axes[4].set_xlabel("time (s)")
    axes[4].legend(loc="upper right", fontsize=7)
    figure.suptitle(f"{clip.name} ({clip.skeleton}, {clip.fps:g} fps): Rempe labels shaded, PhysCap rule as ticks")
    figure.tight_layout()
    out = out_dir / f"labels_{clip.skeleton}_{clip.name}.png"
    figure.savefig(out, dpi=80)
    plt.close(figure)
    print(f"{out}: contact fraction {contacts.mean(axis=0).round(2)}, PhysCap rule "
          f"{physcap.mean(axis=0).round(2)}, stationary {stationary.mean():.2f}")
    return out


def main() -> None:
    out_dir = Path(sys.argv[1])
    out_dir.mkdir(parents=True, exist_ok=True)
    for path in sys.argv[2:]:
        plot_clip(Path(path), out_dir)


if __name__ == "__main__":
    main()
