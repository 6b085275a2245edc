"""Where tensors live: a device given by a user, checked once where it enters the library.

``torch.device("cuda")`` accepts the name on any machine; the first tensor put there then fails
deep inside torch (``AssertionError: Torch not compiled with CUDA enabled``). ``usable_device``
says so where the device is given: ``KinematicModel``, ``TaskModel.load`` and ``.to``, ``lfd-train
--device``.
"""

from __future__ import annotations

import torch

from lfd.errors import error_line

__all__ = ["usable_device"]


def usable_device(device, what: str = "device") -> torch.device:
    """``device`` (a string or ``torch.device``) as a ``torch.device`` this machine can compute
    on, else a ``ValueError`` that names ``what`` and says why (not a device name; CUDA or MPS
    not available; a CUDA index beyond the GPUs present; the meta device, which holds no data)."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError, ValueError) as e:
        raise ValueError(f"{what} must be a torch device (cpu, cuda, cuda:1, mps, ...), got {device!r}") from e
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"{what} {dev}: torch.cuda.is_available() is False on this machine")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise ValueError(f"{what} {dev}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    if dev.type == "mps" and not torch.backends.mps.is_available():
        raise ValueError(f"{what} mps: torch.backends.mps.is_available() is False on this machine")
    if dev.type == "meta":  # tensors there have shapes but no values: nothing can be computed
        raise ValueError(f"{what} meta: the meta device holds no data; use cpu, cuda or mps")
    if dev.type != "cpu":
        try:
            torch.zeros(1, device=dev) + 1
        except (RuntimeError, AssertionError, ValueError, ImportError) as e:
            raise ValueError(f"{what} {dev}: this machine's torch cannot use it ({error_line(e)})") from None
    return dev
