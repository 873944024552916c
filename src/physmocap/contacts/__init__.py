"""Foot contacts (left heel, left toe, right heel, right toe) and the stationary flag, per frame, from 2D keypoints.

- `predict_contacts(obs, mode)`: the shipped networks, causal (online, PhysCap) or centred (offline, Rempe).
- `contacts.train.train_contacts(data_root, out_dir)`: rebuilds the weights from motion capture (needs torch).
- `labels`: the automatic labels of 3D motion; `dataset`: synthetic training data; `noise`: MediaPipe's
  measured errors; `baselines`: the heuristics of Rempe Table 1; `features`: the input representation.
"""

from .labels import CONTACT_SITES, LabelSettings, motion_labels
from .predict import predict_contacts

__all__ = ["CONTACT_SITES", "LabelSettings", "motion_labels", "predict_contacts"]
