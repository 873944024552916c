"""MediaPipe Pose's 33 landmarks: the keypoint order of every observations file."""

LANDMARK_NAMES: tuple[str, ...] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_pinky", "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb",
    "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
NUM_LANDMARKS = len(LANDMARK_NAMES)
LANDMARK_INDEX: dict[str, int] = {name: i for i, name in enumerate(LANDMARK_NAMES)}

# Index of each landmark's mirror image (left <-> right), for flipping data.
MIRRORED: tuple[int, ...] = tuple(
    LANDMARK_INDEX[n.replace("left", "@").replace("right", "left").replace("@", "right")] for n in LANDMARK_NAMES
)


def _sides(pairs: tuple[tuple[str, str], ...]) -> tuple[tuple[str, str], ...]:
    return tuple((a.format(side), b.format(side)) for side in ("left", "right") for a, b in pairs)


# The landmarks as a graph along the body (limb chains, the face and the trunk's four corners), for distances
# measured along the skeleton: the detector's errors correlate along it (contacts/noise.py).
LANDMARK_EDGES: tuple[tuple[str, str], ...] = (
    ("nose", "mouth_left"), ("nose", "mouth_right"), ("mouth_left", "mouth_right"),
    ("left_shoulder", "right_shoulder"), ("left_hip", "right_hip"),
) + _sides((
    ("nose", "{}_eye_inner"), ("{}_eye_inner", "{}_eye"), ("{}_eye", "{}_eye_outer"), ("{}_eye_outer", "{}_ear"),
    ("{}_shoulder", "mouth_{}"), ("{}_shoulder", "{}_elbow"), ("{}_elbow", "{}_wrist"), ("{}_wrist", "{}_pinky"),
    ("{}_wrist", "{}_index"), ("{}_wrist", "{}_thumb"), ("{}_shoulder", "{}_hip"), ("{}_hip", "{}_knee"),
    ("{}_knee", "{}_ankle"), ("{}_ankle", "{}_heel"), ("{}_ankle", "{}_foot_index"), ("{}_heel", "{}_foot_index"),
))
