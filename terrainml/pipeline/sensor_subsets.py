"""Sensor subsets of a model: the members it has, their windows, the groups a replay calls on.

A sensor member (:mod:`terrainml.pipeline.members`) is the model trained again without one sensor
group, so that serving goes on when that group is missing or flagged invalid. This module says
which members a model on some groups has (:func:`member_subsets`), gives a member the model's
windows on its own channels (:func:`subset_dataset`) and says which groups a stretch of logged
runs flags invalid (:func:`flagged_groups`), i.e. which members serving those runs calls on.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np
import pandas as pd

from terrainml.features.windows import channel_sensor_group, groups_read
from terrainml.pipeline.dataset import Dataset
from terrainml.stream.tick.health import SENSOR_TO_GROUP

__all__ = ["MEMBER_DROPS", "member_subsets", "subset_dataset", "flagged_groups"]

#: member name -> the sensor group it does without
MEMBER_DROPS = {"no_imu": "imu", "no_currents": "currents", "no_cam": "cam"}


def member_subsets(sensors: Sequence[str]) -> dict[str, list[str]]:
    """{member name: its sensor groups} for a model on ``sensors`` (order kept).

    A member drops one group of :data:`MEMBER_DROPS` that the model uses; it must keep another
    group besides the wheels (wheel speeds alone are the estimator's input, not a terrain
    signature worth a member). A model on two groups or fewer has no member.
    """
    out = {}
    for name, group in MEMBER_DROPS.items():
        if group not in sensors:
            continue
        rest = [g for g in sensors if g != group]
        if any(g != "wheels" for g in rest):
            out[name] = rest
    return out


def subset_dataset(ds: Dataset, sensors: Sequence[str]) -> Dataset:
    """The windows of ``ds`` restricted to the channels of the groups ``sensors`` (a windows file).

    The channels are those the groups read (:func:`~terrainml.features.channels.groups_read`: a
    member without the camera of a robot that has one also does without the estimator's body
    channels, whose velocity reference the camera is). The windows kept are those every group of
    the model allowed: a run without IMU gives no window to the member without IMU this way
    (``train --windows X`` from logs cuts a member's own windows instead). The selected default
    (``train`` with ``--windows auto``) subsets its chosen spec's windows, so a member shares the
    model's windows and run groups and its windows are not cut again.
    """
    keep = groups_read(sensors, ds.robot)
    chans = [c for c in ds.windows.channels if channel_sensor_group(c) in keep]
    if not chans:
        raise ValueError(f"no window channel left for sensors {list(sensors)}")
    W = ds.windows.select_channels(chans)
    return Dataset(W, ds.runs, ds.counts, ds.robot, replace(ds.spec, channels=tuple(chans)), ds.preset,
                   list(ds.class_ids), list(ds.class_names), ds.class_report)


def flagged_groups(tables: Sequence[pd.DataFrame]) -> set[str]:
    """The sensor groups (``currents``, ``imu``, ``cam``, ...) invalid on some row of the run
    ``tables``: their ``{group}_valid`` flag false there (a log without the group's topic, a
    tracking camera's confidence drop), or the flag absent from a table. These are the groups
    whose members serving those rows calls on (the predictor serves a member while a group its
    model needs is stale or invalid)."""
    out = set()
    for sensor, group in SENSOR_TO_GROUP.items():
        col = f"{group}_valid"
        if any(col not in t.columns or not np.asarray(t[col], dtype=bool).all() for t in tables if len(t)):
            out.add(sensor)
    return out
