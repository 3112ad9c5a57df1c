"""The torch modules of the CNN terrain classifier (:mod:`terrainml.models.cnn`) and the scope of
torch's global state while they train or run.

:class:`ConvNet1d` is the network, :class:`Preprocess` the fixed channel transforms (traction
sense, derived channels), :class:`Standardize` the per-channel standardisation and
:class:`InferenceNet` all three in a row: raw windows ``(n, C, T)`` in, probabilities ``(n, K)``
out (the graph that ONNX export writes). :func:`channel_stats` gives the standardisation
statistics, :func:`torch_context` seeds, threads and deterministic algorithms in a block.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence

import numpy as np
import torch
from torch import nn

from terrainml.features.sets import ROUGHNESS_MIN_SPEED_MPS

__all__ = ["Standardize", "ConvNet1d", "Preprocess", "InferenceNet", "torch_context", "channel_stats"]


class Standardize(nn.Module):
    """Per-channel standardisation ``(x - mean) / scale``; non-finite results become 0.

    Parameters
    ----------
    mean, scale : ndarray of shape (n_channels,)
        Statistics fitted on the training data (``scale`` > 0).
    """

    def __init__(self, mean: np.ndarray, scale: np.ndarray):
        super().__init__()
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean, np.float32)).view(1, -1, 1))
        self.register_buffer("scale", torch.as_tensor(np.asarray(scale, np.float32)).view(1, -1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = (x - self.mean) / self.scale
        return torch.where(torch.isfinite(z), z, torch.zeros_like(z))


class ConvNet1d(nn.Module):
    """Conv blocks (Conv1d, BatchNorm, ReLU, MaxPool) -> global average pool -> dropout -> linear.

    Parameters
    ----------
    n_channels : int
        Input channels C.
    n_classes : int
        Output logits K.
    conv_channels : sequence of int
        Output channels of each block.
    kernel_sizes : sequence of int
        Odd kernel size of each block (same padding).
    dropout : float
        Dropout probability before the linear layer.

    Input ``(n, C, T)`` standardised; output logits ``(n, K)``. Every block but the last halves
    the time axis, so ``T`` must be at least ``2 ** (len(conv_channels) - 1)``.
    """

    def __init__(self, n_channels: int, n_classes: int, conv_channels: Sequence[int],
                 kernel_sizes: Sequence[int], dropout: float, window_stats: bool = False):
        super().__init__()
        self.window_stats = bool(window_stats)
        layers: list[nn.Module] = []
        c_in = n_channels
        n_blocks = len(conv_channels)
        for i, (c_out, k) in enumerate(zip(conv_channels, kernel_sizes)):
            layers += [nn.Conv1d(c_in, c_out, kernel_size=k, padding=k // 2, bias=False),
                       nn.BatchNorm1d(c_out), nn.ReLU()]
            if i < n_blocks - 1:
                layers.append(nn.MaxPool1d(2))
            c_in = c_out
        self.features = nn.Sequential(*layers)
        self.dropout = nn.Dropout(dropout)
        n_head = c_in
        if self.window_stats:
            self.stats_norm = nn.BatchNorm1d(2 * n_channels)
            n_head += 2 * n_channels
        self.head = nn.Linear(n_head, n_classes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = self.features(x).mean(dim=-1)  # global average pooling over time
        if self.window_stats:
            mean = x.mean(dim=-1, keepdim=True)
            std = torch.sqrt(((x - mean) ** 2).mean(dim=-1) + 1e-8)
            z = torch.cat([z, self.stats_norm(torch.cat([mean.squeeze(-1), std], dim=1))], dim=1)
        return self.head(self.dropout(z))


class Preprocess(nn.Module):
    """Fixed input transforms, part of the network (so the ONNX export carries them):

    * traction sense: each wheel's current and slip times the sign of its window-mean current
      (torch version of :func:`terrainml.features.sets.traction_sense`);
    * derived channels appended after the inputs: body ``speed`` = hypot(vx, vy) (m/s) and the
      roughness channels ``imu_az_per_v2`` / ``imu_ax_per_v2`` = (a - window mean) / v^2 with v
      the window-mean speed floored at 0.2 m/s: a surface profile's vibration grows with speed
      squared, so these channels describe the ground rather than the manoeuvre (the same
      invariance the SVM's features use). Derived channels whose inputs are missing are skipped.

    Input ``(n, C, T)`` raw windows; output ``(n, C + n_derived, T)``.
    """

    def __init__(self, channel_names: Sequence[str], traction_sense: bool = True, derived: bool = True):
        super().__init__()
        names = list(channel_names)
        n = len(names)
        owner = torch.full((n,), -1, dtype=torch.long)  # channel -> index of its wheel's current
        if traction_sense:
            for k, c in enumerate(names):
                if c.startswith("current_"):
                    owner[k] = k
                    if f"slip_{c[8:]}" in names:
                        owner[names.index(f"slip_{c[8:]}")] = k
        self.register_buffer("owner", owner)
        self.has_speed = derived and "vx" in names and "vy" in names
        self.i_vx = names.index("vx") if self.has_speed else 0
        self.i_vy = names.index("vy") if self.has_speed else 0
        self.accel_idx = [names.index(c) for c in ("imu_az", "imu_ax") if self.has_speed and c in names]
        self.derived_names = ((["speed"] if self.has_speed else [])
                              + [f"{names[k]}_per_v2" for k in self.accel_idx])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x0 = torch.nan_to_num(x)
        mean = x0.mean(dim=-1)                                           # (n, C)
        sign = torch.where(mean < 0, -torch.ones_like(mean), torch.ones_like(mean))
        per_channel = torch.gather(sign, 1, self.owner.clamp(min=0).view(1, -1).expand_as(sign))
        per_channel = torch.where(self.owner.view(1, -1) >= 0, per_channel, torch.ones_like(per_channel))
        out = [x * per_channel.unsqueeze(-1)]
        if self.has_speed:
            speed = torch.sqrt(x0[:, self.i_vx] ** 2 + x0[:, self.i_vy] ** 2)  # (n, T)
            v2 = torch.clamp(speed.mean(dim=-1, keepdim=True), min=ROUGHNESS_MIN_SPEED_MPS) ** 2
            out.append(speed.unsqueeze(1))
            for k in self.accel_idx:
                a = x0[:, k]
                out.append(((a - a.mean(dim=-1, keepdim=True)) / v2).unsqueeze(1))
        return torch.cat(out, dim=1)


class InferenceNet(nn.Module):
    """Raw windows ``(n, C, T)`` -> class probabilities ``(n, K)`` (preprocess, standardise, net,
    softmax).

    This is exactly what :meth:`CNNClassifier.predict_proba` runs and what is exported to ONNX.
    """

    def __init__(self, standardize: Standardize, net: ConvNet1d, preprocess: Preprocess | None = None):
        super().__init__()
        self.preprocess = preprocess if preprocess is not None else nn.Identity()
        self.standardize = standardize
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.softmax(self.net(self.standardize(self.preprocess(x))), dim=-1)


@contextlib.contextmanager
def torch_context(seed: int | None = None, n_threads: int | None = None,
                  deterministic: bool = False) -> Iterator[None]:
    """Scope torch's global state: seed, thread count, deterministic algorithms; restore after.

    Parameters
    ----------
    seed : int or None
        Seed for torch's global CPU generator inside the block (its state is restored after).
    n_threads : int or None
        ``torch.set_num_threads`` inside the block; ``None`` leaves torch's setting.
    deterministic : bool
        Switch ``torch.use_deterministic_algorithms`` on inside the block.
    """
    old_threads = torch.get_num_threads()
    old_det = torch.are_deterministic_algorithms_enabled()
    old_det_warn = torch.is_deterministic_algorithms_warn_only_enabled()
    with torch.random.fork_rng(devices=[], enabled=seed is not None):
        try:
            if n_threads is not None:
                torch.set_num_threads(int(n_threads))
            if deterministic:
                torch.use_deterministic_algorithms(True)
            if seed is not None:
                torch.manual_seed(int(seed))
            yield
        finally:
            if deterministic:
                torch.use_deterministic_algorithms(old_det, warn_only=old_det_warn)
            if n_threads is not None:
                torch.set_num_threads(old_threads)


def channel_stats(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel mean and scale over windows and time, ignoring non-finite samples.

    Parameters
    ----------
    X : ndarray of shape (n_windows, n_channels, n_timesteps)

    Returns
    -------
    mean, scale : ndarray of shape (n_channels,), float32
        ``scale`` is the standard deviation, replaced by 1 where it is below 1e-8 times
        (1 + |mean|) or undefined (constant or all-missing channel); an all-missing channel has
        mean 0.
    """
    Xd = np.asarray(X, dtype=np.float64)
    finite = np.isfinite(Xd)
    count = finite.sum(axis=(0, 2))
    total = np.where(finite, Xd, 0.0).sum(axis=(0, 2))
    mean = np.divide(total, count, out=np.zeros_like(total), where=count > 0)
    dev = np.where(finite, Xd - mean[None, :, None], 0.0)
    var = np.divide((dev ** 2).sum(axis=(0, 2)), count, out=np.zeros_like(total), where=count > 0)
    std = np.sqrt(var)
    scale = np.where(std > 1e-8 * (1.0 + np.abs(mean)), std, 1.0)
    return mean.astype(np.float32), scale.astype(np.float32)
