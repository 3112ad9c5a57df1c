"""The training loop of the CNN terrain classifier (:mod:`terrainml.models.cnn`).

:func:`inner_split` holds runs out for early stopping (grouped by run, stratified where the runs
allow); :func:`train_network` runs the epochs: AdamW with cosine decay, class-weighted
cross-entropy, batch augmentation (:func:`augment`: gain, noise, time shift), and keeps the
weights of the best validation epoch.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch
from sklearn.metrics import balanced_accuracy_score
from sklearn.model_selection import GroupShuffleSplit, StratifiedGroupKFold
from torch import nn

__all__ = ["inner_split", "train_network", "augment", "TrainingRun"]

log = logging.getLogger("terrainml.models.cnn")


def inner_split(y_idx: np.ndarray, groups: np.ndarray | None, validation_fraction: float,
                seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (train, validation) of the inner early-stopping split, grouped by run."""
    n = len(y_idx)
    everything = np.arange(n)
    if validation_fraction <= 0:
        return everything, everything[:0]
    if groups is None:
        groups = everything  # each window its own group (documented; pass run ids instead)
    groups = np.asarray(groups)
    n_groups = len(np.unique(groups))
    if n_groups < 2:
        log.warning("CNN: only one group (run); early stopping disabled, training all epochs")
        return everything, everything[:0]
    n_splits = max(2, int(round(1.0 / validation_fraction)))
    if n_groups >= n_splits:
        splitter = StratifiedGroupKFold(n_splits=n_splits, shuffle=True, random_state=seed)
        tr, va = next(splitter.split(np.zeros(n), y_idx, groups))
    else:
        splitter = GroupShuffleSplit(n_splits=1, test_size=validation_fraction, random_state=seed)
        tr, va = next(splitter.split(np.zeros(n), y_idx, groups))
    # a class whose runs all landed in validation would never be learned: give them back
    missing = np.setdiff1d(np.unique(y_idx), y_idx[tr])
    if len(missing):
        back = np.isin(groups, groups[va][np.isin(y_idx[va], missing)])
        tr, va = np.flatnonzero(back | np.isin(everything, tr)), np.flatnonzero(~back & np.isin(everything, va))
    return np.sort(tr), np.sort(va)


@dataclass
class TrainingRun:
    """What :func:`train_network` did: ``history`` (per epoch ``epoch``, ``train_loss``,
    ``val_loss``, ``val_balanced_accuracy``), ``best_epoch`` (1-based, the weights kept) and
    ``n_epochs`` (epochs run)."""

    history: list = field(default_factory=list)
    best_epoch: int = 0
    n_epochs: int = 0


def augment(xb: torch.Tensor, gen: torch.Generator, offset: torch.Tensor, cfg) -> torch.Tensor:
    """A training batch ``xb`` (B, C, T), standardised, with a per-window, per-channel gain
    (``offset``: ``mean / scale`` (1, C, 1), so the gain acts on the physical signal), additive
    noise and a time shift with edge replication (``cfg``: :class:`~terrainml.models.cnn.CNNConfig`)."""
    B, C, T = xb.shape
    if cfg.gain_std > 0:
        g = 1.0 + float(cfg.gain_std) * torch.randn(B, C, 1, generator=gen)
        xb = g * xb + (g - 1.0) * offset
    if cfg.noise_std > 0:
        xb = xb + float(cfg.noise_std) * torch.randn(B, C, T, generator=gen)
    if cfg.max_shift > 0:
        shift = torch.randint(-int(cfg.max_shift), int(cfg.max_shift) + 1, (B, 1), generator=gen)
        idx = (torch.arange(T).view(1, T) - shift).clamp_(0, T - 1)
        xb = xb.gather(2, idx.view(B, 1, T).expand(B, C, T))
    return xb


def _class_weights(y_idx: np.ndarray, K: int, classes, balanced: bool) -> torch.Tensor:
    """Cross-entropy class weights ``n / (K * n_k)`` of the training labels (ones when not balanced)."""
    counts = np.bincount(y_idx, minlength=K).astype(np.float64)
    if np.any(counts == 0):
        missing = [classes[k] for k in np.flatnonzero(counts == 0)]
        log.warning("CNN: classes %s have no windows in the inner training part", missing)
    w = np.divide(counts.sum(), K * counts, out=np.zeros(K), where=counts > 0) if balanced else np.ones(K)
    return torch.as_tensor(w, dtype=torch.float32)


def _validate(net: nn.Module, Zva: torch.Tensor, yva: np.ndarray, loss_fn) -> tuple[float, float]:
    """(loss, balanced accuracy) of the network on the validation windows."""
    net.eval()
    with torch.no_grad():
        logits = torch.cat([net(Zva[s:s + 1024]) for s in range(0, len(yva), 1024)])
        loss = float(loss_fn(logits, torch.from_numpy(yva)))
    with warnings.catch_warnings():  # a class may be absent from validation
        warnings.simplefilter("ignore", UserWarning)
        return loss, float(balanced_accuracy_score(yva, logits.argmax(1).numpy()))


def train_network(net: nn.Module, Z: np.ndarray, y_idx: np.ndarray, split: tuple[np.ndarray, np.ndarray],
                  seed: int, cfg, classes, offset: torch.Tensor, n_epochs: int | None = None,
                  verbose: int = 0) -> TrainingRun:
    """Train ``net`` in place on standardised windows ``Z`` (n, C, T) with labels ``y_idx`` (n,)
    (class indices into ``classes``), early-stopped on the ``split`` (train, validation indices).

    ``cfg``: :class:`~terrainml.models.cnn.CNNConfig`; ``offset``: see :func:`augment`;
    ``n_epochs``: epochs to run (None: ``cfg.max_epochs``, stopped after ``cfg.patience`` epochs
    without a better validation score). The weights of the best validation epoch are loaded
    back into ``net`` (the last epoch's without validation windows). ``verbose`` > 0: one log
    line per epoch at INFO level.
    """
    tr, va = split
    gen = torch.Generator().manual_seed(seed)
    Ztr, ytr = torch.from_numpy(Z[tr]), torch.from_numpy(y_idx[tr].astype(np.int64))
    Zva, yva = torch.from_numpy(Z[va]), y_idx[va].astype(np.int64)
    w = _class_weights(y_idx[tr], len(classes), classes, cfg.class_weight == "balanced")
    loss_fn, val_loss_fn = nn.CrossEntropyLoss(weight=w), nn.CrossEntropyLoss(weight=w)
    opt = torch.optim.AdamW(net.parameters(), lr=float(cfg.learning_rate), weight_decay=float(cfg.weight_decay))
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(
        opt, T_max=int(cfg.max_epochs), eta_min=0.05 * float(cfg.learning_rate))
    n_tr = len(tr)
    bs = int(min(cfg.batch_size, n_tr))
    best: tuple = ((-math.inf,), 0)
    best_state = None
    run = TrainingRun()
    for epoch in range(1, int(n_epochs or cfg.max_epochs) + 1):
        net.train()
        perm = torch.randperm(n_tr, generator=gen)
        total, seen = 0.0, 0
        for start in range(0, n_tr, bs):
            idx = perm[start:start + bs]
            if len(idx) < 2:  # BatchNorm needs two samples
                continue
            xb = augment(Ztr[idx], gen, offset, cfg) if cfg.augment else Ztr[idx]
            opt.zero_grad(set_to_none=True)
            loss = loss_fn(net(xb), ytr[idx])
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
            seen += len(idx)
        sched.step()
        record = {"epoch": epoch, "train_loss": total / max(seen, 1),
                  "val_loss": float("nan"), "val_balanced_accuracy": float("nan")}
        if len(va):
            record["val_loss"], record["val_balanced_accuracy"] = _validate(net, Zva, yva, val_loss_fn)
            if cfg.early_stopping_metric == "loss":
                score = (-record["val_loss"],)
            else:  # balanced accuracy first, validation loss breaks ties
                score = (round(record["val_balanced_accuracy"], 9), -record["val_loss"])
            if best_state is None or score > best[0]:
                best = (score, epoch)
                best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        run.history.append(record)
        if verbose:
            log.info("CNN epoch %d: train loss %.4f, val loss %.4f, val bal. acc %.3f", epoch,
                     record["train_loss"], record["val_loss"], record["val_balanced_accuracy"])
        if len(va) and epoch - best[1] >= int(cfg.patience):
            break
    run.n_epochs = len(run.history)
    if best_state is not None:
        net.load_state_dict(best_state)
        run.best_epoch = best[1]
    else:
        run.best_epoch = run.n_epochs
    return run
