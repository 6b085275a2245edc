"""Judging a run as the paper does (``sim.execute``): nothing the arm or its tool touches (table,
containers, obstacles), and at least ``success_fraction`` of the particles inside the bowl once
they have settled. ``ContactLog`` records the touches while the arm moves; ``settle_and_judge``
lets the particles settle and fills the run's verdict."""

from __future__ import annotations

from sim import layout as L
from sim.bullet import p

__all__ = ["TOUCH_DISTANCE", "ContactLog", "settle_and_judge"]

TOUCH_DISTANCE = 0.001  # m: a contact point at most this far apart is a touch


class ContactLog:
    """Contacts of the left arm and the tool with anything but particles.

    PyBullet reports contact points up to its contact-breaking threshold (2 cm) *before* the
    bodies meet, with a positive distance, for some shape pairs (for others only once they
    touch); only points at most ``TOUCH_DISTANCE`` apart (touching or penetrating) are logged,
    so a close pass is not a collision.
    """

    def __init__(self, world):
        self.world, c = world, world.client
        self.arm_links = {idx for name, idx in world.link_index.items()
                          if name.startswith(("left_", "l_gripper")) or name == "tool"} - {-1}
        self.names = {world.table: "table", **{b: n for n, b in world.objects.items()}}
        self.skip = set(world.particles.ids) | {b for n, b in world.objects.items()
                                                if world.object_kind(n) == "marker"}
        self.link_names = {idx: name for name, idx in world.link_index.items()}
        self.c = c
        self.events: list[dict] = []
        self._seen: set = set()

    def poll(self, t_s: float) -> None:
        for cp in p.getContactPoints(bodyA=self.world.robot, physicsClientId=self.c):
            body, link, distance = cp[2], cp[3], cp[8]
            if (body == self.world.robot or body in self.skip or link not in self.arm_links
                    or distance > TOUCH_DISTANCE):
                continue
            key = (body, link)
            if key in self._seen:
                continue
            self._seen.add(key)
            self.events.append({"body": self.names.get(body, str(body)),
                                "link": self.link_names.get(link, str(link)), "t_s": round(t_s, 3),
                                "distance_m": round(float(distance), 4)})


def settle_and_judge(world, contacts: ContactLog, result, s, step: int, frames: list | None) -> None:
    """After the last command (sim step ``step``): let the particles settle for ``s.settle_s``
    (``s``: the run's ``sim.execute.ExecSettings``), then judge the run as the paper does, into
    ``result`` (its ``sim.execute.RunResult``): a contact fails it, else the share of the
    particles in the bowl must reach ``s.success_fraction``."""
    settle = int(s.settle_s / L.SIM_DT)
    for k in range(settle):
        world.step(1)
        if k % 8 == 0:
            contacts.poll((step + k) * L.SIM_DT)
        if frames is not None and s.frame_every and (step + k) % s.frame_every == 0:
            frames.append(world.render(480, 360))
    result.duration_s = (step + settle) * L.SIM_DT
    result.contacts = contacts.events
    result.fraction_in_bowl = world.fraction_in_bowl()
    result.fraction_spilled = world.fraction_spilled()
    hits = sorted({c["body"] for c in result.contacts})
    if hits:
        result.reason = f"collision with {', '.join(hits)}"
    elif result.fraction_in_bowl < s.success_fraction:
        result.reason = (f"only {result.fraction_in_bowl:.0%} of the particles in the bowl "
                         f"(needs {s.success_fraction:.0%})" + (f"; {result.stopped}" if result.stopped else ""))
    else:
        result.success, result.reason = True, "ok"
