"""Reuse of large output tensors once every consumer has let go of them."""

from __future__ import annotations

import torch


def _storage_references(tensor: torch.Tensor) -> int:
    return torch._C._storage_Use_Count(tensor.untyped_storage()._cdata)


class ReusableBuffers:
    """Hands out tensors of one shape, recycling those whose storage nobody outside this pool still holds.

    A fresh multi-megabyte tensor each step is page-faulted in by the OS, which cost more than rendering the
    image into it at thousands of worlds. A buffer is handed out again only when no tensor, view, tensordict or
    numpy array shares its storage any more, so data a caller keeps (a rollout, a replay buffer) is never
    overwritten; a caller that keeps everything just gets fresh tensors, as without the pool.
    """

    def __init__(self, shape: tuple[int, ...], dtype: torch.dtype, device: torch.device, max_buffers: int = 4):
        self.shape, self.dtype, self.device = torch.Size(shape), dtype, device
        self.max_buffers = max_buffers
        self._buffers: list[torch.Tensor] = []
        self._unreferenced = None  # the reference count of a buffer only this pool holds

    def take(self) -> torch.Tensor:
        """An uninitialised tensor of the pool's shape that nobody else references; the caller fills it."""
        for buffer in self._buffers:
            if _storage_references(buffer) == self._unreferenced:
                return buffer
        buffer = torch.empty(self.shape, dtype=self.dtype, device=self.device)
        if self._unreferenced is None:
            self._unreferenced = _storage_references(buffer)
        if len(self._buffers) < self.max_buffers:
            self._buffers.append(buffer)
        return buffer
