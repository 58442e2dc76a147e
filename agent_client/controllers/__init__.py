"""Who drives: one small :class:`Controller` protocol and one factory, :func:`make_controller`.

``vacc drive`` and ``vacc evaluate`` build every controller here; each module is
imported only when its controller is asked for (torch only for ``ddqn``, pygame only
for ``keyboard``, which ``vacc drive`` builds itself inside its window).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

__all__ = ["Controller", "CONTROLLERS", "make_controller", "camera"]

CONTROLLERS = ("acc", "hdm", "ddqn", "human-file", "keyboard")


@runtime_checkable
class Controller(Protocol):
    """Maps a session observation to the normalised force u in [-1, 1] for the next period."""

    name: str

    def reset(self) -> None:
        """Forget the previous episode."""

    def __call__(self, obs: dict[str, Any]) -> float:
        """The force for this observation."""
        ...


def make_controller(name: str, *, seed: int = 0, checkpoint: str | None = None, human_file: Any = None, pad: str = "error") -> Controller:
    """Build a headless controller.

    Args:
        name: "acc", "hdm", "ddqn" or "human-file".
        seed: the episode seed (the Human Driver Model draws its errors from it).
        checkpoint: ``ddqn``: the policy checkpoint.
        human_file: ``human-file``: a read :class:`~agent_client.controllers.human_file.HumanFile`.
        pad: ``human-file``: past the file's end, "error", "hold" or "zero".

    Raises:
        ValueError: an unknown name, or a missing checkpoint or human-file.
        InputFileError: a bad checkpoint.
    """
    if name == "acc":
        from agent_client.controllers.acc import AccController

        return AccController()
    if name == "hdm":
        from agent_client.controllers.hdm import HumanDriverModel

        return HumanDriverModel(seed=seed)  # errors seeded from the episode seed
    if name == "ddqn":
        if checkpoint is None:
            raise ValueError("the ddqn controller needs a checkpoint")
        from agent_client.controllers.ddqn import DDQNController  # torch is imported only here

        return DDQNController.from_checkpoint(checkpoint)
    if name == "human-file":
        if human_file is None:
            raise ValueError("the human-file controller needs a human-file")
        from agent_client.controllers.human_file import HumanFileController

        return HumanFileController(human_file, pad)
    raise ValueError(f"no headless controller {name!r}; one of acc, hdm, ddqn, human-file")


def camera(controller: Any) -> tuple[str, tuple[int, int]]:
    """The camera output a controller needs: (image format, (width, height) [px]).

    A DDQN checkpoint asks for gray at the size its preprocessing needs (its zoom);
    the others drive from the speeds and the gap and need no image.
    """
    cfg = getattr(controller, "cfg", None)
    if cfg is None:
        return "none", (200, 200)
    from agent_client.preprocess import camera_size

    return "gray", camera_size(cfg.zoom)
