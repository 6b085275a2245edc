"""A recording as read from its source, before cleaning and resampling: ``RawRecording``.

Every reader (``lfd.io.recordings`` for CSV files, ``lfd.io.rosbag`` for ROS bags and MCAP)
produces ``RawRecording`` objects; ``lfd.io.recordings.import_raw`` cleans them (dropouts,
repeated readings, outliers, jitter), resamples them and makes the ``DemoSet``, the same way
whatever the source. Readings are kept as the recorder wrote them: a dropout is a reading of
NaN (or the recorder's all-zero pose), not a missing row, so that the cleaning counts it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lfd.errors import UserInputError

__all__ = ["RawRecording", "RawTrack", "RecordingError"]


class RecordingError(UserInputError):
    """A recording that cannot be imported (the message names the file, the row and the reason)."""


@dataclass(frozen=True)
class RawTrack:
    """The readings of one landmark, in the recording's order.

    t : (K,) seconds, on the same clock as the joints' ``RawRecording.t``.
    pose : (K, 7) ``x, y, z, qx, qy, qz, qw`` (metres, quaternion) of the landmark in the
        recording's landmark frame (``T_base_frame`` maps it to the robot's base); a dropout is a
        row with NaN, a zero quaternion, or the all-zero position some recorders write.
    where : (K,) the source's index of each reading, for messages (a CSV's 1-based row, the
        header being row 1; a bag's message number).
    """

    t: np.ndarray
    pose: np.ndarray
    where: np.ndarray

    def __post_init__(self):
        t = np.asarray(self.t, dtype=float).reshape(-1)
        pose = np.asarray(self.pose, dtype=float).reshape(-1, 7)
        where = np.asarray(self.where, dtype=np.int64).reshape(-1)
        if not (len(t) == len(pose) == len(where)):
            raise ValueError(f"RawTrack: t ({len(t)}), pose ({len(pose)}) and where ({len(where)}) differ in length")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "pose", pose)
        object.__setattr__(self, "where", where)


@dataclass(frozen=True)
class RawRecording:
    """One demonstration as recorded.

    name : the demonstration's name (its folder, file stem or bag).
    t : (S,) seconds of each joint reading.
    q : (S, d) joint angles in radians, columns in the robot's ``joint_names`` order (a row with
        NaN: a reading the recorder missed).
    tracks : ``{landmark name: RawTrack}`` in the order the landmarks were first read.
    joint_source, landmark_source : what to name in messages (the file or ``bag:topic``).
    joint_where : (S,) the source's index of each joint reading (CSV row, message number);
        empty: rows 2, 3, ... (a CSV with a header).
    unit : what ``where`` counts, for messages: ``'row'`` or ``'message'``.
    """

    name: str
    t: np.ndarray
    q: np.ndarray
    tracks: dict = field(default_factory=dict)
    joint_source: str = ""
    landmark_source: str = ""
    joint_where: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    unit: str = "row"

    def __post_init__(self):
        t = np.asarray(self.t, dtype=float).reshape(-1)
        q = np.asarray(self.q, dtype=float)
        if q.ndim != 2 or len(q) != len(t):
            raise ValueError(f"RawRecording {self.name!r}: q must be (S, d) with S = len(t) = {len(t)}, "
                             f"got {q.shape}")
        where = np.asarray(self.joint_where, dtype=np.int64).reshape(-1)
        if len(where) == 0:
            where = np.arange(len(t), dtype=np.int64) + 2
        if len(where) != len(t):
            raise ValueError(f"RawRecording {self.name!r}: joint_where has {len(where)} entries, t {len(t)}")
        if not all(isinstance(v, RawTrack) for v in self.tracks.values()):
            raise TypeError(f"RawRecording {self.name!r}: tracks must map names to RawTrack")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "joint_where", where)
        object.__setattr__(self, "tracks", dict(self.tracks))
