"""How far the held-out contact labels move when their thresholds move within the sites' own uncertainty.

The automatic labels (`labels.contact_labels`) read a sole site's height above the floor and its speed. Both are
measurements: the derived heel and toe sites of a flat foot sit at some height over the clip's floor, and a planted
site still shows some speed (jitter, rolling). This script

1. measures those uncertainties on the held-out clips at their own frame rate: the height of every site and its
   speed where both sites of its foot are labelled in contact (flat stance), as percentiles;
2. relabels the held-out test sequences of bench_contacts.py (the same clips, seed 1, 4 variants per clip,
   `held_out_settings`) with the height and speed thresholds moved by those amounts, and counts how many entries
   change, overall and by their distance to the nearest change of the shipped labels;
3. reads the agreement (and F1) as a ceiling: a network that reproduced the shipped-threshold labels exactly would
   score that against labels whose thresholds sit elsewhere within the uncertainty; the last line averages the
   eight moves (every combination of height -, 0, + and speed -, 0, +, but the shipped one).

    nice -n 10 .venv/bin/python scripts/contact_label_uncertainty.py [--height 0.01] [--speed 0.2]

(about 2 minutes, 0.5 GB.)
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import replace
from pathlib import Path

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import numpy as np

from physmocap import metrics
from physmocap.contacts.dataset import (
    SyntheticSettings,
    held_out_settings,
    load_clips,
    make_sequences,
    mocap_files,
    split_by_subject,
)
from physmocap.contacts.labels import (
    CONTACT_SITE_INDICES,
    LabelSettings,
    contact_labels,
    point_speed,
    seconds_to_label_change,
)

MOCAP = Path(__file__).resolve().parents[2] / "shared" / "data" / "mocap"
DISTANCE_BINS = (0.0, 0.025, 0.05, 0.1, 0.2, np.inf)  # s from the nearest change of a site's shipped label
# (bench_contacts.py's bins, 0-0.05 split in two)


def flat_stance_spread(clips) -> dict[str, list[float]]:
    """Percentiles (5, 50, 95) of the sites' heights (m) and speeds (m/s) where both sites of their foot are in
    contact, over every held-out clip at its own frame rate."""
    heights, speeds = [], []
    settings = LabelSettings()
    for clip in clips:
        sites = clip.positions[:, CONTACT_SITE_INDICES]
        contacts = contact_labels(sites, clip.fps, settings)
        speed = point_speed(sites, clip.fps, settings.contact_speed_interval, centred=False)
        for heel, toe in ((0, 1), (2, 3)):
            flat = contacts[:, heel] & contacts[:, toe]
            for site in (heel, toe):
                heights.append(sites[flat, site, 2])
                speeds.append(speed[flat, site])
    percentiles = (5, 50, 95)
    return {"height_m": np.percentile(np.concatenate(heights), percentiles).round(4).tolist(),
            "speed_m_per_s": np.percentile(np.concatenate(speeds), percentiles).round(3).tolist()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--height", type=float, default=0.01, help="height threshold moved by +-this, m")
    parser.add_argument("--speed", type=float, default=0.2, help="speed threshold moved by +-this, m/s")
    args = parser.parse_args()
    _, test_files = split_by_subject(mocap_files(MOCAP))
    clips = load_clips(test_files)
    print(json.dumps({"flat_stance": flat_stance_spread(clips)}), flush=True)
    shipped = LabelSettings()
    base = held_out_settings(SyntheticSettings())
    reference = make_sequences(clips, 1, base, variants=4)
    truth = np.concatenate([s.contacts for s in reference])
    distance = np.concatenate([seconds_to_label_change(s.contacts, s.fps) for s in reference])
    bins = {f"{low}-{high} s": (distance >= low) & (distance < high)
            for low, high in itertools.pairwise(DISTANCE_BINS)}
    shares = {name: round(float(inside.mean()), 4) for name, inside in bins.items()}
    print(json.dumps({"entries": int(truth.size), "share_by_distance": shares}), flush=True)
    agreements, f1s = [], []
    for dh, dv in itertools.product((-args.height, 0.0, args.height), (-args.speed, 0.0, args.speed)):
        if dh == 0.0 and dv == 0.0:
            continue
        labels = replace(shipped, contact_max_height=shipped.contact_max_height + dh,
                         contact_max_speed=shipped.contact_max_speed + dv)
        moved = np.concatenate([s.contacts for s in make_sequences(clips, 1, replace(base, labels=labels), variants=4)])
        agree = moved == truth
        agreements.append(agree)
        f1s.append(metrics.contact_scores(truth, moved)["f1"])  # the shipped labels as the prediction
        print(json.dumps({"height_m": round(shipped.contact_max_height + dh, 3),
                          "speed_m_per_s": round(shipped.contact_max_speed + dv, 2),
                          "agreement": round(float(agree.mean()), 4), "f1": round(f1s[-1], 4),
                          "by_distance": {name: round(float(agree[inside].mean()), 4)
                                          for name, inside in bins.items()}}), flush=True)
    mean = np.mean(agreements, axis=0)
    print(json.dumps({"ceiling_mean_over_moves": round(float(mean.mean()), 4), "f1": round(float(np.mean(f1s)), 4),
                      "by_distance": {name: round(float(mean[inside].mean()), 4) for name, inside in bins.items()}}))


if __name__ == "__main__":
    main()
