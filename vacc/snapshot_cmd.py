"""``vacc snapshot``: render one camera frame and its preprocessed view to PNG files."""

from __future__ import annotations

import math
from pathlib import Path

import click
import cv2
import numpy as np

from agent_client.preprocess import preprocess
from sim_server.render import CameraConfig, Renderer
from sim_server.scene import CarView, SceneState

# traffic colours (RGB); the lead keeps the CarView default red
_PAINT = ((40, 70, 160), (220, 220, 215), (30, 30, 32), (200, 170, 40), (60, 120, 70),
          (150, 150, 160), (120, 30, 100))


def snapshot_scene(gap: float, scenario: str = "ice", seed: int = 0,
                   light_azimuth: float = 0.6, light_elevation: float = 0.8,
                   braking: bool = False) -> SceneState:
    """A scene with the lead ``gap`` metres ahead and a little seeded traffic.

    Traffic as in the world: faster cars on the left lane, slower on the right, and
    oncoming cars beyond the median. The EV scenario (urban-ish speeds) gets denser
    traffic than the ICE freeway one.

    Args:
        gap: host front bumper to lead rear bumper [m].
        scenario: ``ice`` or ``ev``.
        seed: places traffic and roadside scenery.
        light_azimuth: sun azimuth [rad], 0 = ahead, + to the right.
        light_elevation: sun elevation [rad].
        braking: lead's brake lights on.

    Returns:
        The scene to render.
    """
    rng = np.random.default_rng(seed)
    cars = [CarView(dx=gap, lane=0, braking=braking)]
    n = {"ice": 4, "ev": 7}[scenario]
    for _ in range(n):
        lane = int(rng.choice([-1, 1, -2, -3, -4]))
        cars.append(CarView(dx=float(rng.uniform(12.0, 220.0)), lane=lane,
                            color=_PAINT[int(rng.integers(len(_PAINT)))],
                            lateral=float(rng.uniform(-0.3, 0.3))))
    return SceneState(host_s=float(rng.uniform(0.0, 5000.0)), cars=tuple(cars),
                      light_azimuth=light_azimuth, light_elevation=light_elevation,
                      scenery_seed=seed)


def _check_out(ctx: click.Context, param: click.Parameter, value: Path) -> Path:
    if value.suffix.lower() != ".png":
        raise click.BadParameter(f"{value} must end in .png", ctx, param)
    parent = value.parent if str(value.parent) else Path(".")
    if not parent.is_dir():
        raise click.BadParameter(f"directory {parent} does not exist", ctx, param)
    if value.is_dir():
        raise click.BadParameter(f"{value} is a directory", ctx, param)
    return value


@click.command("snapshot")
@click.option("--gap", type=click.FloatRange(min=0.0, max=1000.0), default=50.0, show_default=True,
              help="Distance from the host's front bumper to the lead's rear bumper [m].")
@click.option("--out", "out", type=click.Path(path_type=Path), required=True, callback=_check_out,
              help="PNG file for the camera frame; the preprocessed view goes to NAME.pre.png.")
@click.option("--scenario", type=click.Choice(["ice", "ev"]), default="ice", show_default=True)
@click.option("--seed", type=int, default=0, show_default=True, help="Traffic and scenery seed.")
@click.option("--light-azimuth", type=float, default=0.6, show_default=True,
              help="Sun azimuth [rad]: 0 ahead, + to the right.")
@click.option("--light-elevation", type=click.FloatRange(min=0.0, max=math.pi / 2), default=0.8,
              show_default=True, help="Sun elevation above the horizon [rad].")
@click.option("--braking", is_flag=True, help="Lead car's brake lights on.")
@click.option("--width", type=click.IntRange(min=8, max=4096), default=400, show_default=True,
              help="Image width [px].")
@click.option("--height", type=click.IntRange(min=8, max=4096), default=400, show_default=True,
              help="Image height [px].")
def snapshot(gap: float, out: Path, scenario: str, seed: int, light_azimuth: float,
             light_elevation: float, braking: bool, width: int, height: int) -> None:
    """Render one front-camera frame with the lead car GAP metres ahead.

    Writes OUT (RGB) and, for 400x400 or 200x200 frames, OUT with suffix .pre.png:
    the network's 105x150 grayscale input after the paper's preprocessing.
    """
    scene = snapshot_scene(gap, scenario, seed, light_azimuth, light_elevation, braking)
    img = Renderer(CameraConfig(width=width, height=height)).render(scene)
    if not cv2.imwrite(str(out), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
        raise click.ClickException(f"could not write {out}")
    msg = f"wrote {out} ({width}x{height}, gap {gap:g} m)"
    if (height, width) in ((400, 400), (200, 200)):
        pre_path = out.with_suffix(".pre.png")
        if not cv2.imwrite(str(pre_path), preprocess(img)):
            raise click.ClickException(f"could not write {pre_path}")
        msg += f" and {pre_path}"
    click.echo(msg)
