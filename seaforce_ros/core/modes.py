"""The controller's modes, one small class each, keyed by name (:data:`MODE_TYPES`).

A mode decides what a channel commands when no job runs. Two kinds:

* a :class:`TorqueMode` commands the motor torque F_a [N m] itself: ``passive``, ``hold``,
  ``force_feedback``, ``chirp``;
* a :class:`ReferenceMode` gives the reference F_ref [N m] of the disturbance observer
  (:mod:`.dob`, eq. 19) from the endpoint observer's estimates (:mod:`.observer`): ``dob``,
  ``dob_linear_ff``, ``dob_full_ff``, ``impedance``, ``force``.

What each one does:

* passive: ``F_a = 0``, immediately (the safe state; the one deliberate non-bumpless
  transition).
* hold: ``F_a = bias - K_p (X - X_0) - K_d V`` with X_0 and the bias captured at mode entry.
* force_feedback: ``F_a = K_f F_p + beta`` with a transfer offset beta that decays with a 50 ms
  time constant (bumpless entry; eq. 20).
* chirp: ``F_a = u_0 + A w(t) sin(phi(t))``, log chirp, u_0 the torque at entry, w a 50 ms
  raised-cosine fade-in/out. It plays once per selection of the mode (:meth:`Mode.select`): a
  chirp that finished, or that the plant interrupted (:meth:`Mode.interrupt`), never plays
  again by itself after a reset or re-entry.
* dob: ``F_ref = 0`` (eq. 19).
* dob_linear_ff: ``F_ref = F_cmp`` (eq. 29).
* dob_full_ff: ``F_ref = F_cmp + F_d`` (eq. 29 and 14: minimum impedance).
* impedance: ``F_ref = F_cmp + F_d - K_t (X_e_hat - X_e0) - B_t V_e_hat``, X_e0 captured at mode
  entry: the endpoint renders the target stiffness/damping (plus the endpoint inertia).

The feed-forward terms carry the margin of :mod:`.observer` (``feedforward.margin``: the low
edge of the model's uncertainty): the friction left uncompensated is at least zero.
* force: ``F_ref = target.force`` (eq. 19 with a reference): at rest the hose pushes the motor
  with ``F_p = -F_ref``.

Bumpless transfer: a torque mode's :meth:`TorqueMode.enter` returns the first output from the
torque the plant applies (``full`` entry: the targets are captured; otherwise a re-entry after
the plant replaced the torque for a moment, which keeps them); the DOB makes the reference
modes' entries bumpless. ``steps`` (int >= 1) is the number of sample periods since the
previous sample: decays and clocks advance over the real elapsed time.
"""

from __future__ import annotations

import math
from typing import ClassVar

from .observer import EndpointObserver
from .params import ControllerConfig
from .signals import faded_log_chirp

__all__ = ["Mode", "TorqueMode", "ReferenceMode", "Passive", "Hold", "ForceFeedback", "Chirp",
           "Dob", "DobLinearFeedforward", "DobFullFeedforward", "Impedance", "Force",
           "MODE_TYPES", "TRANSFER_TIME", "CHIRP_FADE"]

TRANSFER_TIME = 0.05    # s, decay of the force-feedback and hold transfer offsets
CHIRP_FADE = 0.05       # s, raised-cosine fade of the chirp envelope


class Mode:
    """One mode of one channel: configured from the channel's
    :class:`~.params.ControllerConfig`, entered bumplessly, updated per sample.

    Parameters
    ----------
    config : ControllerConfig
    dt : float > 0
        Sample period T [s].
    """

    #: The mode's name (a :data:`~.params.MODES` entry).
    name: ClassVar[str] = ""
    #: Its output includes the endpoint friction feed-forward (the friction adaptation may
    #: run in it).
    uses_feedforward: ClassVar[bool] = False

    __slots__ = ("dt",)

    def __init__(self, config: ControllerConfig, dt: float = 5e-4) -> None:
        self.dt = float(dt)
        self.configure(config)
        self.reset()

    def configure(self, config: ControllerConfig) -> None:
        """New (validated) parameters; the state is kept."""

    def reset(self) -> None:
        """Forget what was captured at entry (the next sample enters the mode)."""

    def select(self) -> None:
        """The mode was configured (anew): a chirp plays again."""

    def interrupt(self) -> None:
        """The plant interrupted the channel (a reset, a re-entry, a job taking over)."""


class TorqueMode(Mode):
    """A mode that commands the motor torque F_a itself."""

    __slots__ = ()

    def enter(self, x: float, v: float, f_p: float, steps: int, torque: float,
              full: bool) -> float:
        """The first sample in the mode: X [rad], V [rad/s], F_p [N m], the torque the plant
        applies [N m]; ``full``: capture the targets (else keep them: a re-entry). Returns
        F_a [N m] (``torque`` but for passive)."""
        return self.update(x, v, f_p, steps)

    def update(self, x: float, v: float, f_p: float, steps: int) -> float:
        """One sample: F_a [N m]."""
        raise NotImplementedError


class ReferenceMode(Mode):
    """A mode that gives the DOB's reference F_ref from the endpoint observer."""

    __slots__ = ()

    def enter(self, obs: EndpointObserver) -> float:
        """The first sample after a full entry (targets captured): F_ref [N m]."""
        return self.update(obs)

    def update(self, obs: EndpointObserver) -> float:
        """One sample: F_ref [N m]."""
        raise NotImplementedError


class Passive(TorqueMode):
    """``F_a = 0``."""

    name = "passive"
    __slots__ = ()

    def enter(self, x: float, v: float, f_p: float, steps: int, torque: float,
              full: bool) -> float:
        return 0.0

    def update(self, x: float, v: float, f_p: float, steps: int) -> float:
        return 0.0


class Hold(TorqueMode):
    """``F_a = bias - K_p (X - X_0) - K_d V`` (+ a decaying transfer offset after a
    re-entry)."""

    name = "hold"
    __slots__ = ("_kp", "_kd", "_decay", "_x0", "_bias", "_transfer")

    def configure(self, config: ControllerConfig) -> None:
        self._kp, self._kd = config.hold.stiffness, config.hold.damping
        self._decay = math.exp(-self.dt / TRANSFER_TIME)

    def reset(self) -> None:
        self._x0 = self._bias = self._transfer = 0.0

    def enter(self, x: float, v: float, f_p: float, steps: int, torque: float,
              full: bool) -> float:
        """Full entry: X_0 = X and the bias that makes F_a = ``torque``; re-entry: the targets
        kept, the step to ``torque`` taken up by the transfer offset."""
        if full:
            self._x0 = x
            self._bias = torque + self._kd * v
            self._transfer = 0.0
        u = self._bias - self._kp * (x - self._x0) - self._kd * v
        if not full:
            self._transfer = torque - u
        return u + self._transfer

    def update(self, x: float, v: float, f_p: float, steps: int) -> float:
        u = self._bias - self._kp * (x - self._x0) - self._kd * v
        if self._transfer:
            self._transfer *= self._decay if steps == 1 else self._decay ** steps
        return u + self._transfer


class ForceFeedback(TorqueMode):
    """``F_a = K_f F_p + beta``, beta decaying from the entry's offset (eq. 20)."""

    name = "force_feedback"
    __slots__ = ("_kf", "_decay", "_bias")

    def configure(self, config: ControllerConfig) -> None:
        self._kf = config.force_feedback.gain
        self._decay = math.exp(-self.dt / TRANSFER_TIME)

    def reset(self) -> None:
        self._bias = 0.0

    def enter(self, x: float, v: float, f_p: float, steps: int, torque: float,
              full: bool) -> float:
        self._bias = torque - self._kf * f_p
        return self._kf * f_p + self._bias

    def update(self, x: float, v: float, f_p: float, steps: int) -> float:
        self._bias *= self._decay if steps == 1 else self._decay ** steps
        return self._kf * f_p + self._bias


class Chirp(TorqueMode):
    """``F_a = u_0 + A w(t) sin(phi(t))``, once per selection.

    Attributes
    ----------
    played : bool
        The chirp has finished or was interrupted: entering again holds u_0.
    """

    name = "chirp"
    __slots__ = ("_amplitude", "_f0", "_f1", "_duration", "_fade", "played", "_t", "_bias",
                 "_interrupted", "_next", "_playing")

    def __init__(self, config: ControllerConfig, dt: float = 5e-4) -> None:
        self.played = False
        self._interrupted = False
        self._playing = False        # entered, from its start, and not yet played
        super().__init__(config, dt)

    def configure(self, config: ControllerConfig) -> None:
        """New values; a chirp that plays goes on with those it was selected with (a new
        amplitude, band or duration taken up at once stepped the torque: 0.3 -> 3 N m gave
        -0.30 -> -2.97 N m), the new ones from its next selection."""
        c = config.chirp
        self._next = (c.amplitude, c.start_frequency, c.end_frequency, c.duration,
                      min(CHIRP_FADE, 0.1 * c.duration))
        if self.played or not self._playing:
            self._take()

    def _take(self) -> None:
        self._amplitude, self._f0, self._f1, self._duration, self._fade = self._next

    def reset(self) -> None:
        """The clock to zero (``played`` is kept: a reset does not replay the chirp)."""
        self._t = self._bias = 0.0
        self._playing = False

    def select(self) -> None:
        self.played = self._playing = False     # (the newest values: at the entry)

    def interrupt(self) -> None:
        self._interrupted = True
        if self._t > 0.0:
            self.played = True

    def enter(self, x: float, v: float, f_p: float, steps: int, torque: float,
              full: bool) -> float:
        """Full entry (selected anew) or after an interruption: u_0 = ``torque``, the chirp
        from its start -- or, played, not again. A re-entry with no interruption (new values
        set within the mode): it goes on, its clock and u_0 kept."""
        if full or self.played or self._interrupted:
            self._interrupted = False
            self._bias = torque
            if self.played:
                self._t = self._duration
            else:                       # from its start, with the newest values
                self._take()
                self._t = 0.0
                self._playing = True
            return self._output()
        return self.update(x, v, f_p, steps)

    def update(self, x: float, v: float, f_p: float, steps: int) -> float:
        self._t += self.dt * steps
        return self._output()

    def _output(self) -> float:
        t = self._t
        if t >= self._duration:
            self.played = True
        return self._bias + self._amplitude * faded_log_chirp(t, self._f0, self._f1,
                                                              self._duration, self._fade)


class Dob(ReferenceMode):
    """``F_ref = 0``: the DOB alone (eq. 19)."""

    name = "dob"
    __slots__ = ()

    def update(self, obs: EndpointObserver) -> float:
        return 0.0


class DobLinearFeedforward(ReferenceMode):
    """``F_ref = F_cmp`` (eq. 29)."""

    name = "dob_linear_ff"
    uses_feedforward = True
    __slots__ = ()

    def update(self, obs: EndpointObserver) -> float:
        return obs.compensation


class DobFullFeedforward(ReferenceMode):
    """``F_ref = F_cmp + F_d`` (eq. 29 and 14): minimum impedance."""

    name = "dob_full_ff"
    uses_feedforward = True
    __slots__ = ()

    def update(self, obs: EndpointObserver) -> float:
        return obs.feedforward


class Impedance(ReferenceMode):
    """``F_ref = F_cmp + F_d - K_t (X_e_hat - X_e0) - B_t V_e_hat``, X_e0 captured at entry."""

    name = "impedance"
    uses_feedforward = True
    __slots__ = ("_kt", "_bt", "_x0")

    def configure(self, config: ControllerConfig) -> None:
        self._kt, self._bt = config.target.stiffness, config.target.damping

    def reset(self) -> None:
        self._x0 = 0.0

    def enter(self, obs: EndpointObserver) -> float:
        self._x0 = obs.position
        return self.update(obs)

    def update(self, obs: EndpointObserver) -> float:
        return (obs.feedforward - self._kt * (obs.position - self._x0)
                - self._bt * obs.velocity)


class Force(ReferenceMode):
    """``F_ref = target.force`` (eq. 19 with a reference)."""

    name = "force"
    __slots__ = ("_f_ref",)

    def configure(self, config: ControllerConfig) -> None:
        self._f_ref = config.target.force

    def update(self, obs: EndpointObserver) -> float:
        return self._f_ref


#: Every mode's class, by name (the keys are :data:`~.params.MODES`).
MODE_TYPES: dict[str, type[Mode]] = {cls.name: cls for cls in (
    Passive, Hold, ForceFeedback, Dob, DobLinearFeedforward, DobFullFeedforward, Impedance,
    Force, Chirp)}
