"""The two contact networks' architectures and their numpy inference (the product runs without torch).

Both read the inputs of `features.window_inputs` and give five logits per predicted frame: left heel, left toe,
right heel, right toe contact, stationary (OUTPUT_NAMES).

- Causal (PhysCap 4.2, after Zou et al. 2020): the last 7 frames; temporal convolutions (kernel 3, no padding,
  each followed by batch normalisation and ReLU) shrink the window 7 -> 5 -> 3 -> 1 frames, then one fully
  connected layer. The frame interval enters as one more input channel, constant over the window.
- Centred (Rempe 3.2, A.2): 9 frames centred on the target; an MLP 1024-512-128-32 with batch normalisation and
  ReLU after every hidden layer, then a linear layer to 5 frames x 5 outputs for the 5 central frames.

Weights are stored as float32 arrays in an .npz file with batch normalisation folded into the preceding layer:
- causal: "conv{i}.weight" (kernel, in, out), "conv{i}.bias" (out,), "fc.weight" (in, 5), "fc.bias" (5,).
- centred: "linear{i}.weight" (in, out), "linear{i}.bias" (out,), the last one with 25 outputs (frame-major).
An ensemble (`members` > 1: networks of different training seeds whose probabilities are averaged) stores every
array with one more leading axis, one index per member (`stack_members`, `ensemble_members`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .features import CAUSAL_WINDOW, CENTRED_WINDOW, NUM_FEATURE_POINTS, VALUES_PER_POINT, WindowSpec

OUTPUT_NAMES: tuple[str, ...] = ("left_heel", "left_toe", "right_heel", "right_toe", "stationary")
NUM_OUTPUTS = len(OUTPUT_NAMES)
FRAME_CHANNELS = NUM_FEATURE_POINTS * VALUES_PER_POINT  # 48 values per frame


@dataclass(frozen=True)
class CausalNetSpec:
    """Causal temporal-convolution network. channels: output channels of each convolution (their number must
    shrink the window to one frame: (length - 1) / (kernel - 1) layers); kernel: frames per convolution;
    dropout: before the fully connected layer, training only; members: networks trained with different seeds
    whose probabilities are averaged, 1 (one network) to about 5, each costing one more forward pass;
    member_data_draws: member m >= 1 trains on its own draw of synthetic sequences (data seed + 100 m), not on
    member 0's (for the causal network that widened its spread on real frames: contact-training.md)."""

    window: WindowSpec = CAUSAL_WINDOW
    channels: tuple[int, ...] = (128, 128, 128)
    kernel: int = 3
    dropout: float = 0.2
    members: int = 3
    member_data_draws: bool = False

    def __post_init__(self) -> None:
        if (self.window.length - 1) != len(self.channels) * (self.kernel - 1):
            raise InputError(
                f"CausalNetSpec: {len(self.channels)} convolutions of kernel {self.kernel} do not shrink "
                f"{self.window.length} frames to one."
            )


@dataclass(frozen=True)
class CentredNetSpec:
    """Centred MLP (Rempe A.2: hidden sizes 1024, 512, 128, 32; dropout before the 128 layer, 0.1 where Rempe has
    0.3: better on validation subjects, see contacts/train.py). members, member_data_draws: as for CausalNetSpec
    (three members on their own draws gained on both validation seeds: contact-training.md)."""

    window: WindowSpec = CENTRED_WINDOW
    hidden: tuple[int, ...] = (1024, 512, 128, 32)
    dropout: float = 0.1
    dropout_before_layer: int = 2
    members: int = 3
    member_data_draws: bool = True


_ONE_NETWORK_DIMENSIONS = {"conv0.weight": 3, "linear0.weight": 2}  # a single network's first weight


def stack_members(members: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """One parameter set holding the networks `members` (same architecture) as an ensemble."""
    if len(members) == 1:
        return members[0]
    return {key: np.stack([member[key] for member in members]) for key in members[0]}


def ensemble_members(params: dict[str, np.ndarray]) -> list[dict[str, np.ndarray]]:
    """The networks of a parameter set: itself when it is one network, else each member of its ensemble."""
    first = "conv0.weight" if "conv0.weight" in params else "linear0.weight"
    if params[first].ndim == _ONE_NETWORK_DIMENSIONS[first]:
        return [params]
    return [{key: value[index] for key, value in params.items()} for index in range(len(params[first]))]


def sigmoid(logits: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * logits))


def causal_forward(params: dict[str, np.ndarray], inputs: np.ndarray) -> np.ndarray:
    """Logits (N, 5) of the causal network for inputs (N, 7 x 48 + 1) (`features.window_inputs`)."""
    count = len(inputs)
    length = (inputs.shape[1] - 1) // FRAME_CHANNELS
    hidden = np.empty((count, length, FRAME_CHANNELS + 1), dtype=np.float32)
    hidden[..., :-1] = inputs[:, :-1].reshape(count, length, FRAME_CHANNELS)
    hidden[..., -1] = inputs[:, -1:]
    layer = 0
    while f"conv{layer}.weight" in params:
        weight, bias = params[f"conv{layer}.weight"], params[f"conv{layer}.bias"]
        kernel = len(weight)
        out_length = hidden.shape[1] - kernel + 1
        out = np.broadcast_to(bias, (count, out_length, len(bias))).copy()
        for k in range(kernel):
            out += hidden[:, k : k + out_length] @ weight[k]
        hidden = np.maximum(out, 0.0)
        layer += 1
    return hidden[:, 0] @ params["fc.weight"] + params["fc.bias"]


def centred_forward(params: dict[str, np.ndarray], inputs: np.ndarray) -> np.ndarray:
    """Logits (N, 5 frames, 5) of the centred network for inputs (N, 9 x 48 + 1); frames t-2 .. t+2."""
    hidden = inputs
    layer = 0
    while f"linear{layer + 1}.weight" in params:
        hidden = np.maximum(hidden @ params[f"linear{layer}.weight"] + params[f"linear{layer}.bias"], 0.0)
        layer += 1
    logits = hidden @ params[f"linear{layer}.weight"] + params[f"linear{layer}.bias"]
    return logits.reshape(len(inputs), -1, NUM_OUTPUTS)
