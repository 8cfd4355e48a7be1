"""Small CPU launches recorded once and replayed (on a GPU, plain launches).

`wp.launch` packs every argument anew, 10-40 us a call on a CPU, which for the few dozen
blocks a scan allocates or lifts into the coarse levels costs more than the kernel itself. A
recorded launch replays in about 2 us; its dimension and scalar arguments are set in place
(about 1 us each), and it is recorded again when an array argument is another object.
"""

from __future__ import annotations

import operator

import warp as wp


class Replay:
    """One kernel's launch on one CPU device, replayed while its array arguments stay the same
    objects (it holds them, so an array it was recorded with stays alive until it is recorded
    again or `forget` is called)."""

    def __init__(self, kernel, device):
        self.kernel = kernel
        self.device = device
        self._command = None
        self._args: list = []
        self._dim = 0

    def forget(self) -> None:
        """Drop the recorded launch and the arrays it holds (their owner replaced them)."""
        self._command, self._args = None, []

    def __call__(self, dim: int, inputs: list, outputs: list) -> None:
        """wp.launch(kernel, dim, inputs, outputs) on the device (on a GPU, launched as it is:
        its launches queue without waiting); dim > 0."""
        if self.device.is_cuda:
            wp.launch(self.kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device)
            return
        args = [*inputs, *outputs]
        command, old = self._command, self._args
        if command is None or len(args) != len(old):
            command = self._record(dim, inputs, outputs)
        elif not all(map(operator.is_, args, old)):  # a scalar changed, or an array was replaced
            for i, (new, was) in enumerate(zip(args, old)):
                if new is was:
                    continue
                if isinstance(new, wp.array) or isinstance(was, wp.array):
                    command = self._record(dim, inputs, outputs)
                    break
                if new != was:
                    command.set_param_at_index(i, new)
                old[i] = new
        if dim != self._dim:
            command.set_dim(dim)
            self._dim = dim
        command.launch()

    def _record(self, dim: int, inputs: list, outputs: list):
        command = wp.launch(self.kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device, record_cmd=True)
        self._command, self._args, self._dim = command, [*inputs, *outputs], dim
        return command
