"""Blackman-Tukey frequency-response estimates with 1-sigma bands.

Cross-spectra with respect to a reference signal r (the measured excitation: the external
chirp torque F_e, or the motor torque F_a for a motor chirp)::

    R_ry(tau) = 1/N sum_t r(t) y(t + tau)           (biased estimate, via FFT)
    S_ry(w)   = sum_{|tau| <= M} w_M(tau) R_ry(tau) e^{-j w tau T}

with a Hann lag window ``w_M`` of half-length M. A log chirp needs a frequency-dependent
resolution (MATLAB's ``spafdr``): at frequency w the window spans about ``periods`` periods,
``M(w) ~ periods 2 pi/(w T)`` (rounded down to a power of two, at most ``N/4``), i.e. a
resolution of about w/periods. Each window length is evaluated by one FFT (8x zero-padded) and
interpolated at the grid frequencies it serves.

A frequency response y/u is estimated as the ratio of cross-spectra with the reference,
``H = S_ry/S_ru``: noise on u and y that is uncorrelated with r (pressure noise, encoder
quantisation) drops out, unlike ``S_uy/S_uu``, which is biased by noise on the input u.

1-sigma band (first-order, Ljung 1999 sec. 6.4): with ``nu(w) = N/sum_tau w_M(tau)^2``
independent estimates and coherences ``g2_ry, g2_ru``::

    var(H)/|H|^2 = 1/(2 nu) [(1 - g2_ry)/g2_ry + (1 - g2_ru)/g2_ru]

It treats the chirp as a stationary signal: with a log chirp the energy near w is spread over
only part of the record, so the bands are a lower bound at the low end of the band.

Signals with a ``delay`` (in samples) are shifted before the estimate: a torque *held* over the
sample interval that starts at its sample time (the sim's external torque, a drive's command)
acts like the sampled value delayed by half a sample (``delay=0.5``); the recorded motor effort
of a cycle was applied during the interval *before* the sample (``delay=-0.5``).
"""

from __future__ import annotations

import functools
import math
from typing import Dict, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__all__ = ["BlackmanTukey", "FrequencyResponse", "hann_lag_window", "Spectra"]

_Real = npt.NDArray[np.float64]
_Complex = npt.NDArray[np.complex128]
#: ``(S_ry, S_yy)`` of one signal: its cross-spectrum with the reference and its auto-spectrum.
Spectra = Tuple[_Complex, _Real]
#: Samples of a signal (indexed, so not any array_like).
Samples = Union[Sequence[float], _Real]


@functools.lru_cache(maxsize=64)
def hann_lag_window(m: int) -> _Real:
    """Hann lag window of half-length ``m`` at lags ``-m..m`` (``w(0) = 1``, ``w(+-m) = 0``)."""
    tau = np.arange(-m, m + 1)
    w = 0.5 * (1.0 + np.cos(np.pi * tau / m))
    w.setflags(write=False)
    return w


class FrequencyResponse:
    """A frequency response estimate on a grid.

    Attributes
    ----------
    omega : array [rad/s]
    h : complex array
    rel_sigma : array, 1-sigma of |H| relative to |H| (also of the phase, in rad)
    name : str
    """

    def __init__(self, omega: npt.ArrayLike, h: npt.ArrayLike, rel_sigma: npt.ArrayLike,
                 name: str = "") -> None:
        self.omega = np.asarray(omega, float)
        self.h = np.asarray(h, complex)
        self.rel_sigma = np.asarray(rel_sigma, float)
        self.name = name

    @property
    def sigma(self) -> _Real:
        """Absolute 1-sigma [units of H]."""
        return np.abs(self.h) * self.rel_sigma

    def band(self, lo: float, hi: float) -> "FrequencyResponse":
        """Copy restricted to ``lo <= omega <= hi``."""
        sel = (self.omega >= lo) & (self.omega <= hi)
        return FrequencyResponse(self.omega[sel], self.h[sel], self.rel_sigma[sel], self.name)


class BlackmanTukey:
    """Blackman-Tukey cross-spectra of many signals against one reference.

    Parameters
    ----------
    reference : array
        r, the excitation (mean removed internally).
    dt : float > 0
        Sample period [s].
    omega : array of float > 0
        Frequency grid [rad/s].
    periods : float > 0
        Periods of w inside the lag window (resolution ~ w/periods).
    reference_delay : float
        Delay of r in samples of ``dt`` (see module docstring).
    decimate : int >= 1 or 'auto'
        Work on every q-th sample after a zero-phase FIR anti-alias filter (scipy's
        ``decimate``): the spectra above ``omega.max()`` are not needed, and long records
        (10 min at 2 kHz) get q times cheaper. 'auto' keeps the new Nyquist frequency at least
        2.5x above the grid. Delays stay in samples of the original ``dt``.
    """

    def __init__(self, reference: npt.ArrayLike, dt: float, omega: npt.ArrayLike,
                 periods: float = 10.0, reference_delay: float = 0.0,
                 decimate: Union[int, str] = 1) -> None:
        r = np.asarray(reference, float)
        if r.ndim != 1 or r.size < 16:
            raise ValueError("reference must be a 1-D array of at least 16 samples")
        omega = np.asarray(omega, float)
        if decimate == "auto":
            decimate = max(1, int(math.pi / (dt * 2.5 * omega.max())))
        self.q = int(decimate)
        self.n_full = r.size
        self.dt_full = float(dt)
        r = self._decimate(r)
        self.n = r.size
        self.dt = float(dt) * self.q
        self.omega = np.asarray(omega, float)
        self.periods = float(periods)
        self.nfft = 1 << int(math.ceil(math.log2(2 * self.n)))
        max_lag = max(8, self.n // 4)
        wanted = self.periods * 2.0 * np.pi / (self.omega * self.dt)
        levels = np.floor(np.log2(np.clip(wanted, 8, max_lag))).astype(int)
        self.lags = (1 << levels).astype(int)            # M(w) per grid point
        self._levels = sorted(set(self.lags.tolist()))
        self._r_delay = float(reference_delay) * self.dt_full
        self._fr = np.fft.rfft(r - r.mean(), self.nfft)
        #: equivalent number of independent estimates nu(w) = N / sum w^2
        self.nu = self.n / (0.75 * self.lags + 0.5)
        self._auto_r = self._spectrum(self._fr, self._fr).real
        self._cache: Dict[str, Spectra] = {}

    def _spectrum(self, fa: _Complex, fb: _Complex) -> _Complex:
        """BT estimate of S_ab on the grid from the FFTs of a and b."""
        corr = np.fft.irfft(np.conj(fa) * fb, self.nfft) / self.n   # R_ab(tau), circular
        out = np.empty(self.omega.size, complex)
        for m in self._levels:
            sel = self.lags == m
            w = hann_lag_window(m)
            length = 8 * m if 8 * m >= 2 * m + 1 else 2 * m + 1
            buf = np.zeros(length)
            buf[:m + 1] = corr[:m + 1] * w[m:]
            buf[-m:] = corr[-m:] * w[:m]
            spec = np.fft.rfft(buf)                                  # at k 2 pi/(length T)
            grid = np.arange(spec.size) * 2.0 * np.pi / (length * self.dt)
            out[sel] = (np.interp(self.omega[sel], grid, spec.real)
                        + 1j * np.interp(self.omega[sel], grid, spec.imag))
        return out

    def _decimate(self, y: _Real) -> _Real:
        if self.q == 1:
            return y
        import scipy.signal
        return scipy.signal.decimate(y - y.mean(), self.q, ftype="fir", zero_phase=True)

    def _fft(self, y: Samples, order: int = 0) -> _Complex:
        y = np.asarray(y, float)
        if y.shape != (self.n_full,):
            raise ValueError(f"signal must have {self.n_full} samples")
        y = self._decimate(y)
        y = y - y.mean()
        for _ in range(order):
            y = np.diff(y, prepend=y[0])
        return np.fft.rfft(y, self.nfft)

    def _difference(self, order: int) -> _Complex:
        """Frequency response of ``order`` backward differences over T, on the grid."""
        z = 1.0 - np.exp(-1j * self.omega * self.dt)
        return z ** order  # type: ignore[return-value]  # numpy's stubs: float - complex

    def cross(self, y: Samples, delay: float = 0.0, order: int = 0) -> _Complex:
        """S_ry on the grid (``delay`` of y in samples, relative to the reference's).

        ``order`` backward differences prewhiten y before the estimate (positions fall by
        40 dB/decade above the resonances; without prewhitening the lag window leaks their
        low-frequency power into the high-frequency estimates); the result is divided by the
        differences' exact response, so it is the spectrum of y itself.
        """
        s = self._spectrum(self._fr, self._fft(y, order))
        if order:
            s = s / self._difference(order)
        return self._shifted(s, delay * self.dt_full - self._r_delay)

    def delayed(self, s_ry: _Complex, delay: float) -> _Complex:
        """``cross(y, delay)`` from ``s_ry = cross(y)``: one estimate serves several alignments
        of y (an external force held over the sample or sampled at its instant)."""
        return self._shifted(s_ry, delay * self.dt_full)

    def _shifted(self, s: _Complex, shift: float) -> _Complex:
        """``s`` delayed by ``shift`` seconds (a phase of ``-omega shift``)."""
        if shift:
            return s * np.exp(-1j * self.omega * shift)
        return s

    def auto(self, y: Samples, order: int = 0) -> _Real:
        """S_yy on the grid (real, clipped at a tiny positive value); ``order`` as in
        :meth:`cross`."""
        fy = self._fft(y, order)
        s = np.maximum(self._spectrum(fy, fy).real, 1e-300)
        if order:
            s = s / np.abs(self._difference(order)) ** 2
        return s

    def signal(self, name: str, y: Samples, delay: float = 0.0,
               orders: Optional[Sequence[Tuple[int, float]]] = None) -> Spectra:
        """Cross- and auto-spectrum of a named signal, cached: ``(S_ry, S_yy)``.

        ``orders``: prewhitening per band, a sequence of ``(order, upper_omega)`` (the first
        band starts at 0), e.g. ``((0, 5.0), (1, 60.0), (2, inf))`` for a position;
        default: no prewhitening.
        """
        if name not in self._cache:
            if not orders:
                orders = ((0, np.inf),)
            s_ry = np.empty(self.omega.size, complex)
            s_yy = np.empty(self.omega.size)
            lo = -np.inf
            for order, hi in orders:
                sel = (self.omega > lo) & (self.omega <= hi)
                lo = hi
                if sel.any():
                    s_ry[sel] = self.cross(y, delay, order)[sel]
                    s_yy[sel] = self.auto(y, order)[sel]
            self._cache[name] = (s_ry, s_yy)
        return self._cache[name]

    def coherence(self, s_ry: _Complex, s_yy: _Real) -> _Real:
        """Squared coherence |S_ry|^2/(S_rr S_yy), clipped to (0, 1]."""
        g2 = np.abs(s_ry) ** 2 / (np.maximum(self._auto_r, 1e-300) * s_yy)
        return np.clip(g2, 1e-12, 1.0)

    def response(self, output: Spectra, inp: Spectra, name: str = "") -> FrequencyResponse:
        """H = y/u from two ``(S_r., S_..)`` pairs (see :meth:`signal`) with its band."""
        s_ry, s_yy = output
        s_ru, s_uu = inp
        h = s_ry / s_ru
        g_y = self.coherence(s_ry, s_yy)
        g_u = self.coherence(s_ru, s_uu)
        rel_var = ((1.0 - g_y) / g_y + (1.0 - g_u) / g_u) / (2.0 * self.nu)
        return FrequencyResponse(self.omega, h, np.sqrt(rel_var), name)
