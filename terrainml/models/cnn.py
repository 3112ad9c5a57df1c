"""1-D convolutional terrain classifier on raw windows (design §8-9), scikit-learn style.

The input is a stack of raw windows ``X`` of shape ``(n_windows, n_channels, n_timesteps)``
(for the reference robot: channels ``slip_1..N, current_1..N, vx, vy, r, imu_ax, imu_ay,
imu_az`` at 100 Hz, 200 samples = 2 s). The network is small on purpose (about 26 k weights
for 12 channels): three convolution blocks (Conv1d, BatchNorm, ReLU, max-pooling on the first
two), global average pooling over time, dropout and one linear layer::

    x (n, C, T) -> standardise per channel -> [Conv1d k7 -> BN -> ReLU -> MaxPool 2]
                -> [Conv1d k5 -> BN -> ReLU -> MaxPool 2] -> [Conv1d k3 -> BN -> ReLU]
                -> mean over time -> concat(per-channel window mean and std, BN)
                -> Dropout -> Linear -> softmax (n, K)

The window-statistics branch (``window_stats=True``) hands the linear layer each channel's
window mean and standard deviation: slip and current levels carry much of the terrain
information, and a data set of a few thousand windows learns them faster this way.

Training (``CNNClassifier.fit``):

* per-channel standardisation: mean and standard deviation over all windows and time steps of
  the data given to ``fit`` (the training fold only; nothing is taken from prediction data).
  Non-finite samples (e.g. slip when the camera dropped out) become 0 after standardisation,
  i.e. the training mean;
* early stopping on an inner validation split grouped by run: the first fold of a seeded
  ``StratifiedGroupKFold`` (``round(1 / validation_fraction)`` folds) over the ``groups`` given
  to ``fit``, so no run is in both parts and every class with enough runs is validated; with
  fewer runs than folds a seeded ``GroupShuffleSplit``. A class whose runs all fall into the
  validation part is moved back to training (it could not be learned otherwise). The split is
  stratified because a random group split of ~15 runs regularly leaves a class out of the
  validation set;
* light augmentation of each training batch (in standardised units): a per-window,
  per-channel gain ``1 + gain_std * N(0, 1)``, additive Gaussian noise ``noise_std`` and a
  time shift of up to ``max_shift`` samples with edge replication;
* AdamW, cross-entropy with balanced class weights (as the SVM's ``class_weight="balanced"``),
  cosine learning-rate decay; the weights of the epoch with the best validation balanced
  accuracy (ties: lowest validation loss) are kept; training stops after ``patience`` epochs
  without improvement.

Determinism: with an integer ``random_state`` the weight initialisation, the shuffling, the
augmentation and dropout all draw from generators seeded by it, and torch's deterministic
algorithms are switched on while fitting, so the same seed on the same machine and thread
count gives identical weights and predictions. The global torch RNG state, the
deterministic-algorithms flag and the thread count are restored afterwards. ``n_threads``
sets ``torch.set_num_threads`` for fit and predict (``None`` leaves torch's setting alone).

Modules: the network and its fixed transforms are in :mod:`terrainml.models.cnn_net`, the
training loop in :mod:`terrainml.models.cnn_training`, persistence (``cnn_weights.safetensors``
and ``cnn_config.json``, no pickle, never ``torch.load``) in :mod:`terrainml.models.cnn_files`,
ONNX export in :mod:`terrainml.models.onnx_export`. This module holds the estimator: its
hyper-parameters (:class:`CNNConfig`, one frozen record) and the scikit-learn API.
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass, fields

import numpy as np
import torch
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.utils.validation import check_is_fitted, check_random_state

from terrainml.models.cnn_net import ConvNet1d, InferenceNet, Preprocess, Standardize, channel_stats, torch_context
from terrainml.models.cnn_training import inner_split, train_network

__all__ = ["CNNClassifier", "CNNConfig"]


@dataclass(frozen=True)
class CNNConfig:
    """The network and training hyper-parameters of :class:`CNNClassifier` (checked at ``fit``).

    Attributes
    ----------
    conv_channels : tuple of int, default (32, 64, 64)
        Output channels of each convolution block.
    kernel_sizes : tuple of int, default (7, 5, 3)
        Odd kernel size (samples) of each block; same length as ``conv_channels``.
    dropout : float in [0, 1), default 0.2
        Dropout before the linear layer.
    learning_rate : float > 0, default 3e-3
        AdamW learning rate (cosine-decayed to 5% over ``max_epochs``).
    weight_decay : float >= 0, default 1e-2
        AdamW decoupled weight decay.
    batch_size : int >= 2, default 64
    max_epochs : int >= 1, default 150
    patience : int >= 1, default 40
        Stop when the early-stopping score has not improved for this many epochs.
    validation_fraction : float in [0, 0.5], default 0.2
        Share of runs (groups) held out for early stopping; 0 trains ``max_epochs`` epochs.
    class_weight : {"balanced", None}, default "balanced"
        Cross-entropy class weights ``n / (K * n_k)`` from the inner training part.
    augment : bool, default True
        Gain, noise and time-shift augmentation of training batches.
    gain_std : float >= 0, default 0.05
        Standard deviation of the per-window, per-channel multiplicative gain.
    noise_std : float >= 0, default 0.05
        Additive Gaussian noise, in standardised units.
    max_shift : int >= 0, default 20
        Largest time shift in samples (20 = 0.2 s at 100 Hz), edges replicated.
    window_stats : bool, default True
        Also feed each window's per-channel mean and standard deviation (standardised units,
        batch-normalised) to the linear layer, beside the pooled convolution features: the
        level of slip and current carries much of the terrain information and a small data
        set learns it faster this way.
    early_stopping_metric : {"balanced_accuracy", "loss"}, default "balanced_accuracy"
        Validation score that picks the kept epoch: balanced accuracy (ties broken by the
        lower loss) or the (class-weighted) cross-entropy.
    refit : bool, default True
        After early stopping, train a fresh network on all windows (validation runs included)
        for the chosen number of epochs (twice the training time; uses every run). Measured on
        the simulated dataset: the weakest outer folds 0.92-0.94 -> 0.95-0.97 balanced accuracy;
        early stopping on 20% of the runs is noisy and the held-out runs are worth training on.
    traction_sense : bool, default True
        Multiply each wheel's current and slip by the sign of its window-mean current before
        standardising (see :func:`terrainml.features.sets.traction_sense`): wheels driven
        backwards then look like wheels driven forwards. Part of the exported network.
    derived_channels : bool, default True
        Append body speed and the speed-normalised vibration channels ``imu_az_per_v2``,
        ``imu_ax_per_v2`` to the input (see :class:`~terrainml.models.cnn_net.Preprocess`;
        measured on the simulated dataset: grouped-CV balanced accuracy of the weakest folds
        0.80/0.86 -> 0.88/0.96). Part of the exported network.
    """

    conv_channels: tuple = (32, 64, 64)
    kernel_sizes: tuple = (7, 5, 3)
    dropout: float = 0.2
    learning_rate: float = 3e-3
    weight_decay: float = 1e-2
    batch_size: int = 64
    max_epochs: int = 150
    patience: int = 40
    validation_fraction: float = 0.2
    class_weight: str | None = "balanced"
    augment: bool = True
    gain_std: float = 0.05
    noise_std: float = 0.05
    max_shift: int = 20
    window_stats: bool = True
    early_stopping_metric: str = "balanced_accuracy"
    refit: bool = True
    traction_sense: bool = True
    derived_channels: bool = True


#: the field names of :class:`CNNConfig`
CONFIG_FIELDS = frozenset(f.name for f in fields(CNNConfig))


def _channels_of(X) -> list[str] | None:
    """Channel names carried by a ``Windows``-like input (``.X`` and ``.channels``), else None."""
    if hasattr(X, "channels") and hasattr(X, "X"):
        return [str(c) for c in X.channels]
    return None


def _as_int_tuple(value, name: str) -> tuple[int, ...]:
    try:
        out = tuple(int(v) for v in value)
    except TypeError:
        raise ValueError(f"{name} must be a sequence of positive ints, got {value!r}") from None
    if not out or any(v <= 0 for v in out) or any(o != v for o, v in zip(out, value)):
        raise ValueError(f"{name} must be a non-empty sequence of positive ints, got {value!r}")
    return out




class CNNClassifier(ClassifierMixin, BaseEstimator):
    """1-D CNN on raw windows, with the scikit-learn classifier API.

    Parameters
    ----------
    config : CNNConfig or None, default None
        Network and training hyper-parameters (None: the defaults). :meth:`from_params` builds
        the estimator from flat hyper-parameters (``max_epochs=20, patience=5, ...``).
    channel_names : sequence of str or None, default None
        Names of the C input channels, stored with the model (``ch0..`` when None).
    random_state : int, numpy Generator/RandomState or None, default None
        Seed of every random process in ``fit``; an int makes ``fit`` reproducible.
    n_threads : int or None, default None
        ``torch.set_num_threads`` during fit/predict; None leaves torch's setting.
    verbose : int, default 0
        Log one line per epoch at INFO level when > 0.

    Attributes
    ----------
    classes_ : ndarray of shape (K,)
        Class labels seen in ``fit`` (sorted), any hashable labels (ints or strings).
    n_channels_in_, n_timesteps_in_ : int
        Input shape seen in ``fit``; ``predict`` needs the same C (T may differ).
    channel_names_ : list of str
    mean_, scale_ : ndarray of shape (C,), float32
        Standardisation statistics of the training data.
    model_ : InferenceNet
        The trained network (eval mode), raw windows in, probabilities out.
    history_ : list of dict
        Per epoch: ``epoch``, ``train_loss``, ``val_loss``, ``val_balanced_accuracy``.
    best_epoch_, n_epochs_ : int
        Epoch whose weights were kept (1-based), epochs run.
    fit_time_s_ : float
        Wall time of ``fit`` in seconds.
    """

    def __init__(self, config: CNNConfig | None = None, channel_names=None, random_state=None, n_threads=None,
                 verbose=0):
        self.config = config
        self.channel_names = channel_names
        self.random_state = random_state
        self.n_threads = n_threads
        self.verbose = verbose

    @classmethod
    def from_params(cls, **params) -> "CNNClassifier":
        """The estimator of flat hyper-parameters: :class:`CNNConfig` fields and this class's own
        (``channel_names``, ``random_state``, ``n_threads``, ``verbose``); an unknown name raises
        TypeError. Nothing is checked before ``fit`` (scikit-learn's convention)."""
        own = {k: v for k, v in params.items() if k not in CONFIG_FIELDS}
        cfg = {k: v for k, v in params.items() if k in CONFIG_FIELDS}
        return cls(CNNConfig(**cfg), **own)

    @property
    def config_(self) -> CNNConfig:
        """The hyper-parameters in use (``config``, or the defaults)."""
        return self.config if self.config is not None else CNNConfig()

    def _preprocess_module(self) -> Preprocess:
        cfg = self.config_
        return Preprocess(self.channel_names_, bool(cfg.traction_sense), bool(cfg.derived_channels))

    # ---- sklearn plumbing ------------------------------------------------------------------
    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.two_d_array = False
        tags.input_tags.three_d_array = True
        tags.input_tags.allow_nan = True
        tags.non_deterministic = self.random_state is None
        return tags

    def _check_params(self) -> None:
        cfg = self.config_
        if not isinstance(cfg, CNNConfig):
            raise ValueError(f"CNNClassifier: config must be a CNNConfig, got {cfg!r}")

        def number(name, lo, hi=math.inf, lo_open=False, integer=False):
            v = getattr(self if name in ("verbose", "n_threads") else cfg, name)
            kind = numbers.Integral if integer else numbers.Real
            if isinstance(v, bool) or not isinstance(v, kind) or not math.isfinite(float(v)):
                raise ValueError(f"CNNClassifier: {name} must be a {'int' if integer else 'number'}, got {v!r}")
            if (v <= lo if lo_open else v < lo) or v > hi:
                raise ValueError(f"CNNClassifier: {name}={v!r} out of range "
                                 f"{'(' if lo_open else '['}{lo}, {hi}]")

        chans = _as_int_tuple(cfg.conv_channels, "conv_channels")
        kernels = _as_int_tuple(cfg.kernel_sizes, "kernel_sizes")
        if len(chans) != len(kernels):
            raise ValueError("CNNClassifier: conv_channels and kernel_sizes must have the same "
                             f"length, got {len(chans)} and {len(kernels)}")
        if any(k % 2 == 0 for k in kernels):
            raise ValueError(f"CNNClassifier: kernel_sizes must be odd, got {kernels}")
        number("dropout", 0.0, 0.999)
        number("learning_rate", 0.0, lo_open=True)
        number("weight_decay", 0.0)
        number("batch_size", 2, integer=True)
        number("max_epochs", 1, integer=True)
        number("patience", 1, integer=True)
        number("validation_fraction", 0.0, 0.5)
        number("gain_std", 0.0, 1.0)
        number("noise_std", 0.0)
        number("max_shift", 0, integer=True)
        number("verbose", 0, integer=True)
        if cfg.early_stopping_metric not in ("balanced_accuracy", "loss"):
            raise ValueError("CNNClassifier: early_stopping_metric must be 'balanced_accuracy' or "
                             f"'loss', got {cfg.early_stopping_metric!r}")
        if cfg.class_weight not in ("balanced", None):
            raise ValueError(f"CNNClassifier: class_weight must be 'balanced' or None, got {cfg.class_weight!r}")
        for flag in ("augment", "window_stats", "refit"):
            if not isinstance(getattr(cfg, flag), (bool, np.bool_)):
                raise ValueError(f"CNNClassifier: {flag} must be a bool, got {getattr(cfg, flag)!r}")
        if self.n_threads is not None:
            number("n_threads", 1, integer=True)

    def _align_channels(self, X):
        """Reorder a ``Windows`` input to the training channel order by name."""
        names = _channels_of(X)
        if names is None or names == list(self.channel_names_):
            return X
        missing = [c for c in self.channel_names_ if c not in names]
        if missing:
            raise ValueError(f"CNNClassifier: window channels {missing} missing (the model was "
                             f"trained on {list(self.channel_names_)}, got {names})")
        return np.asarray(X.X)[:, [names.index(c) for c in self.channel_names_], :]

    @staticmethod
    def _check_X(X, n_channels: int | None = None) -> np.ndarray:
        X = np.asarray(X.X if _channels_of(X) is not None else X)
        if X.dtype == object or not np.issubdtype(X.dtype, np.number):
            raise ValueError(f"CNNClassifier: X must be numeric, got dtype {X.dtype}")
        if X.ndim != 3:
            raise ValueError("CNNClassifier: X must have shape (n_windows, n_channels, n_timesteps), "
                             f"got an array with {X.ndim} dimension(s) {X.shape}")
        if X.shape[0] == 0:
            raise ValueError("CNNClassifier: X has no windows")
        if n_channels is not None and X.shape[1] != n_channels:
            raise ValueError(f"CNNClassifier: X has {X.shape[1]} channels, the model was trained on {n_channels}")
        return np.ascontiguousarray(X, dtype=np.float32)

    # ---- fit -------------------------------------------------------------------------------
    def fit(self, X, y, groups=None, channel_names=None):
        """Train on raw windows.

        Parameters
        ----------
        X : array-like of shape (n_windows, n_channels, n_timesteps), or ``Windows``
            Raw windows in physical units (NaN allowed: treated as the channel mean). A
            :class:`~terrainml.features.windows.Windows` brings its channel names and run ids.
        y : array-like of shape (n_windows,)
            Class labels (any hashable; at least two classes).
        groups : array-like of shape (n_windows,), optional
            Run id of each window; the early-stopping split never splits a run. Default: the
            run ids of a ``Windows`` input; otherwise each window is its own group (windows of
            one run then leak between the parts).
        channel_names : sequence of str, optional
            Names of the C channels (overrides the ``channel_names`` parameter and the names
            a ``Windows`` input carries).

        Returns
        -------
        self
        """
        t0 = time.perf_counter()
        self._check_params()
        X, groups, classes, y_idx, names = self._fit_inputs(X, y, groups, channel_names)
        n, C, T = X.shape
        seed = int(check_random_state(self.random_state).randint(0, 2**31 - 1))
        self.channel_names_ = names
        pre = self._preprocess_module()
        with torch.inference_mode():  # the same fixed transforms the exported network applies
            X = np.ascontiguousarray(pre(torch.from_numpy(X)).numpy(), dtype=np.float32)
        C_net = X.shape[1]

        mean, scale = channel_stats(X)
        self.classes_ = classes
        self.n_channels_in_, self.n_timesteps_in_ = C, T
        self.n_net_channels_ = C_net
        self.mean_, self.scale_ = mean, scale

        Z = (X - mean[None, :, None]) / scale[None, :, None]
        Z = np.where(np.isfinite(Z), Z, np.float32(0.0)).astype(np.float32)
        cfg = self.config_
        split = inner_split(y_idx, groups, float(cfg.validation_fraction), seed)
        # a gain g on the raw signal x is g * z + (g - 1) * mean / scale in standardised units z
        offset = torch.as_tensor(mean / scale).view(1, -1, 1)

        def fresh_net() -> ConvNet1d:
            return ConvNet1d(C_net, len(classes), cfg.conv_channels, cfg.kernel_sizes, float(cfg.dropout),
                             bool(cfg.window_stats))

        with torch_context(seed, self.n_threads, deterministic=True):
            net = fresh_net()
            run = train_network(net, Z, y_idx, split, seed, cfg, classes, offset, verbose=self.verbose)
            self.history_, self.best_epoch_, self.n_epochs_ = run.history, run.best_epoch, run.n_epochs
            if cfg.refit and len(split[1]):
                # retrain from scratch on every window (validation runs included) for the
                # number of epochs early stopping chose
                net = fresh_net()
                everything = (np.arange(n), np.arange(0))
                refit = train_network(net, Z, y_idx, everything, seed, cfg, classes, offset, n_epochs=run.best_epoch,
                                      verbose=self.verbose)
                self.refit_history_ = refit.history
            net.eval()
        self.model_ = InferenceNet(Standardize(mean, scale), net, pre).eval()
        for p in self.model_.parameters():
            p.requires_grad_(False)
        self.fit_time_s_ = time.perf_counter() - t0
        return self

    def _fit_inputs(self, X, y, groups, channel_names):
        """Checked inputs of :meth:`fit`: X (n, C, T), groups (or None), classes, labels as class
        indices, channel names (ValueError names a bad shape or too short windows)."""
        if groups is None and hasattr(X, "groups") and hasattr(X, "channels"):
            groups = X.groups
        given_names = _channels_of(X)
        X = self._check_X(X)
        n, C, T = X.shape
        y = np.asarray(y)
        if y.ndim != 1 or len(y) != n:
            raise ValueError(f"CNNClassifier: y must have shape ({n},), got {y.shape}")
        if groups is not None:
            groups = np.asarray(groups)
            if groups.shape != (n,):
                raise ValueError(f"CNNClassifier: groups must have shape ({n},), got {groups.shape}")
        n_blocks = len(self.config_.conv_channels)
        if T < 2 ** (n_blocks - 1):
            raise ValueError(f"CNNClassifier: windows of {T} samples are too short for "
                             f"{n_blocks} blocks (need >= {2 ** (n_blocks - 1)})")
        classes, y_idx = np.unique(y, return_inverse=True)
        if len(classes) < 2:
            raise ValueError(f"CNNClassifier: need at least 2 classes, got {classes.tolist()}")
        if channel_names is None:
            channel_names = self.channel_names if self.channel_names is not None else given_names
        if channel_names is None:
            names = [f"ch{i}" for i in range(C)]
        else:
            names = [str(c) for c in channel_names]
            if len(names) != C:
                raise ValueError(f"CNNClassifier: {len(names)} channel_names for {C} channels")
        return X, groups, classes, y_idx, names

    # ---- predict ---------------------------------------------------------------------------
    def predict_proba(self, X) -> np.ndarray:
        """Class probabilities.

        Parameters
        ----------
        X : array-like of shape (n_windows, n_channels, n_timesteps), or ``Windows``
            Raw windows, same channels (order and units) as in ``fit``; a ``Windows`` input is
            reordered by channel name (a missing channel raises ValueError naming it).

        Returns
        -------
        ndarray of shape (n_windows, n_classes), float64
            Columns in the order of ``classes_``; rows sum to 1.
        """
        check_is_fitted(self, "model_")
        X = self._check_X(self._align_channels(X), self.n_channels_in_)
        xt = torch.from_numpy(X)
        with torch_context(None, self.n_threads), torch.inference_mode():
            out = [self.model_(xt[s:s + 2048]) for s in range(0, len(xt), 2048)]
        return torch.cat(out).numpy().astype(np.float64)

    def predict(self, X) -> np.ndarray:
        """Most probable class per window, shape (n_windows,), labels from ``classes_``."""
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]

    # ---- persistence (terrainml.models.cnn_files) ------------------------------------------
    def save(self, directory) -> list:
        """Write ``cnn_weights.safetensors`` and ``cnn_config.json`` into ``directory``; the two
        files written (for the artifact manifest). See :func:`~terrainml.models.cnn_files.save_cnn`."""
        from terrainml.models.cnn_files import save_cnn  # noqa: PLC0415 - persistence imports this module

        return save_cnn(self, directory)

    @classmethod
    def load(cls, directory) -> "CNNClassifier":
        """Rebuild a fitted classifier from :meth:`save` output (no pickle, no ``torch.load``);
        ValueError names a missing or invalid file. See :func:`~terrainml.models.cnn_files.load_cnn`."""
        from terrainml.models.cnn_files import load_cnn  # noqa: PLC0415 - persistence imports this module

        return load_cnn(directory)

    def n_parameters(self) -> int:
        """Number of trainable weights of the fitted network."""
        check_is_fitted(self, "model_")
        return int(sum(p.numel() for p in self.model_.net.parameters()))
