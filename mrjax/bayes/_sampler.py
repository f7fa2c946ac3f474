"""The settings of the one sampler of mrjax (:class:`Sampler` and its kernels :class:`NUTS`
and :class:`ChEES`) on any problem kind's residual function.

A problem kind supplies a residual function of one *unit*'s unknowns (one condition of a
per-test fit; the whole data set of a joint-law fit),

    residual(theta (K,), unit_data) -> ((r (R1, T1), mask (R1, T1)), (r, mask), ...)

a tuple of blocks of records (rows) by samples, masked samples unscored, and the unknowns'
box. :func:`sample` builds one log-density per unit (the Gaussian likelihood of
`mrjax.bayes.block_loglik` with one noise level per record and, for `noise="ar1"`, one AR(1)
coefficient per unit; the priors of `mrjax.bayes.log_prior` through the bounded map
`to_box` with its log-Jacobian), starts the chains around the posterior's mode with a metric
from the Hessian there (found by damped Newton from the polished optimum, in the coordinates
of the Gauss-Newton covariance of the residuals there; one unknown held per direction the
data leave undetermined), and draws with the kernel of `Sampler.kernel`
(`mrjax.bayes._chains`): NUTS, each chain adapted and run on its own (Stan's windows,
`blackjax.window_adaptation`), or ChEES-HMC, the chains of every unit of a page in lockstep
in one vmapped batch, each unit's step size, trajectory length and metric tuned from its
chains together (`blackjax.chees_adaptation`).

The sampler's position is `z = [u (Kf), log s (R), v]`: `u` the unknowns it moves in the
bounded map (the free ones, less those held in every unit and the linear ones integrated out:
see `linear` in :func:`sample`); `log s` [log N] the records' noise levels, with `"ar1"`
those of the innovations,
$s = \\sigma \\sqrt{1 - \\rho^2}$ ($\\sigma$ the marginal level that is reported): on a real
record $\\rho \\to 1$ and the data fix $s$ tightly but $\\sigma$ only through each record's
first sample, so $(\\log\\sigma, v)$ is a long narrow ridge that NUTS crosses in hundreds of
steps, while $(\\log s, v)$ is not (the change is a shear: flat priors stay flat, Jeffreys'
for a scale); `v` with $\\rho = \\tanh v$ (`"ar1"` only; uniform prior on
$\\rho \\in (-1, 1)$).
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import equinox as eqx
import jax
import numpy as np

from .._errors import InputError

#: Default target acceptance of the step-size adaptation, by kernel and the model's kind (see
#: `Sampler.target_accept`).
TARGET_ACCEPT = {"static": 0.9, "dynamic": 0.8}
#: Default further rounds for the units that missed convergence (see `Sampler.continuations`),
#: and the highest target acceptance a continued unit that diverged is given.
CONTINUATIONS = 2
CONTINUED_TARGET = 0.995
#: ChEES's default target for the harmonic mean of its chains' acceptance: above the optimum
#: of jittered HMC on a Gaussian (0.651), where the tanh model's AR(1) posteriors on long
#: records diverged now and then (a diverging unit is warmed up again), at about the same
#: leapfrog steps per draw (`benchmarks/posterior.md`).
CHEES_TARGET = 0.8
#: Chains start at the mode plus this many starting standard deviations of noise (a start
#: with a non-finite log-density falls back onto the mode).
JITTER = 1.0
#: Draws whose linear unknowns (integrated out of the log-density) are drawn side by side.
LINEAR_BATCH = 64
#: What `Sampler.vectorize` may name: every chain of every unit in one batch, the chains of
#: one unit at a time, or none (one chain after another).
VECTORIZE: tuple[str, ...] = ("all", "chains", "none")


class AbstractKernel(eqx.Module):
    """A kernel of :class:`Sampler`: how the chains move and are tuned (:class:`NUTS`,
    :class:`ChEES`). `DRAWS`, `CHAINS`, `WARMUP` are its defaults for `Sampler.draws`,
    `chains` and `warmup`; `target_accept(dynamic)` its default target acceptance rate."""

    DRAWS: ClassVar[int]
    CHAINS: ClassVar[int]
    WARMUP: ClassVar[int]

    @abc.abstractmethod
    def target_accept(self, dynamic: bool) -> float:
        """The default target acceptance rate for a dynamic model (or a static one)."""

    @property
    def name(self) -> str:
        """The kernel's name in files (`posterior.nc`'s attributes, fit.json)."""
        return f"blackjax {type(self).__name__}"


class NUTS(AbstractKernel):
    """The No-U-Turn sampler (`blackjax.nuts`), every chain adapted on its own with Stan's
    windows (`blackjax.window_adaptation`: step size, then a dense or diagonal mass matrix,
    `Sampler.dense_mass`), trees of at most 2^`Sampler.max_doublings` - 1 leapfrog steps.
    Each chain's tree has its own depth: chains batched by `vmap` wait for the deepest at
    every draw, so chains and units are mapped or vmapped as `Sampler.vectorize` says.

    Defaults: 4 chains x (500 warmup + 1,000 draws); target acceptance 0.9 for a static
    model (Stan: 0.8; short records leave its parameters strongly correlated, and smaller
    steps avoid divergent transitions at little cost), 0.8 for a dynamic one (every leapfrog
    step an integration). The chains start at the posterior's mode with the inverse of its
    Hessian as metric, so the adaptation has less to find than Stan's 1,000 steps assume
    (`benchmarks/posterior.md`).
    """

    DRAWS: ClassVar[int] = 1000
    CHAINS: ClassVar[int] = 4
    WARMUP: ClassVar[int] = 500

    def target_accept(self, dynamic: bool) -> float:
        return TARGET_ACCEPT["dynamic" if dynamic else "static"]


class ChEES(AbstractKernel):
    """ChEES-HMC (Hoffman, Radul & Sountsov 2021; `blackjax.chees_adaptation`): jittered HMC
    whose chains of one unit share a step size and a trajectory length, tuned from all of
    them at every warmup step (the step size by dual averaging on their harmonic-mean
    acceptance, the length by Adam on the ChEES criterion), so that the chains of a unit, and
    with `Sampler.vectorize` `"all"` all the chains of all the units of a page, move in
    lockstep in one vmapped batch, one leapfrog step each per batch step. Each unit's
    metric is the inverse Hessian at its mode, re-estimated during the warmup
    from its chains' covariance (`mrjax.bayes._chains.WINDOWS`: the coordinates re-whitened,
    a dense mass matrix per unit). Its continuations extend the chains of the units that
    missed (no new warmup) unless they diverged.

    **Fields:**

    - `max_leapfrog`: the most leapfrog steps of one trajectory.
    - `learning_rate`: Adam's learning rate on the log trajectory length.
    - `page`: units per compiled batch (the memory bound: a batch holds `page x chains`
        chains' residuals and Jacobians); None: all units in one page up to
        `PAGE_CHAINS` chains, else as many pages of equal size as needed.

    Defaults (`Sampler`): 8 chains x (150 warmup + 300 draws); target acceptance
    `CHEES_TARGET`. The chains start at the mode with its inverse Hessian as metric: 150
    warmup steps tune them as well as 300 (the same leapfrog steps per draw and ESS on the
    tanh AR(1) posteriors of the real records), and 2,400 draws give every test ESS >= 400;
    the split R-hat's own noise then leaves about half the tests of a campaign above 1.01,
    and their chains are extended (`Sampler.continuations`), which costs less than longer
    chains for every test. The same draws as 16 chains of half the length leave R-hat above
    1.01 more often (twice the half-chains, each half as long; `benchmarks/posterior.md`).
    """

    max_leapfrog: int = eqx.field(static=True, default=256)
    learning_rate: float = eqx.field(static=True, default=0.05)
    page: int | None = eqx.field(static=True, default=None)

    DRAWS: ClassVar[int] = 300
    CHAINS: ClassVar[int] = 8
    WARMUP: ClassVar[int] = 150
    #: Chains a default page holds at most.
    PAGE_CHAINS: ClassVar[int] = 1024

    def __check_init__(self):
        for name in ("max_leapfrog", "page"):
            v = getattr(self, name)
            if v is None and name == "page":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise InputError(f"ChEES {name} must be a positive integer, got {v!r}")
        if not (isinstance(self.learning_rate, (int, float)) and self.learning_rate > 0):
            raise InputError(f"ChEES learning_rate must be positive, got "
                             f"{self.learning_rate!r}")

    def target_accept(self, dynamic: bool) -> float:
        return CHEES_TARGET

    def page_size(self, units: int, chains: int) -> int:
        """Units per page for `units` units of `chains` chains: `page`, else all in one page up
        to `PAGE_CHAINS` chains, else equal pages of at most that many chains."""
        if self.page is not None:
            return min(int(self.page), units)
        n_pages = -(-units * chains // self.PAGE_CHAINS)
        return -(-units // max(n_pages, 1))


class Sampler(eqx.Module):
    """Settings of the sampler (all static: a new value compiles a new program).

    **Fields:**

    - `draws`: draws kept per chain (after warmup); None: the kernel's default
        (`NUTS`: 1,000; `ChEES`: 300).
    - `chains`: independent chains per unit; None: the kernel's default (`NUTS`: 4;
        `ChEES`: 8).
    - `warmup`: adaptation steps per chain; None: the kernel's default (`NUTS`: 500;
        `ChEES`: 150).
    - `target_accept`: the step-size adaptation's target acceptance rate (NUTS: the mean
        acceptance of each tree; ChEES: the harmonic mean over a unit's chains); None: the
        kernel's default for the model (:meth:`for_model`).
    - `max_doublings`: NUTS tree depth cap (at most 2^max_doublings - 1 leapfrog steps).
    - `dense_mass`: NUTS: adapt a dense inverse mass matrix (default; the damper models'
        parameters trade off, e.g. modified Bouc-Wen's z-scale) or a diagonal one.
    - `vectorize`: NUTS: `True` (or `"all"`) vmaps every chain of every unit into one batch;
        `"chains"` vmaps the chains of a unit and runs the units one after another; `False`
        (or `"none"`) runs every chain one after another with `lax.map`; all in one compiled
        program. `None` (default): `"all"` on an accelerator; on a CPU `"chains"` for a
        forward-mode gradient (a dynamic model: one sequential integration, whose small
        steps leave a CPU's vector units idle, so a batch of chains costs little more than
        one), else `"none"`: a vmapped NUTS step runs until the longest trajectory of its
        batch ends, so where one chain's residuals already fill the vector units (a static
        model on a record) the batch only adds work (`benchmarks/posterior.md`). With
        several CPU devices the chains of a unit are also spread over them
        (:func:`chain_devices`). ChEES: `"all"` vmaps every chain of every unit of a page
        (with several CPU devices, each runs pages of its own), `"chains"` vmaps the chains of one unit
        at a time, `"none"` steps them one after another (still in lockstep: one step size
        and trajectory length per unit); `None`: `"all"` on an accelerator or for a
        forward-mode gradient, else `"chains"` (a static model: its units' trajectory
        lengths differ, and a unit of a batch would wait for the longest; a unit's chains
        take the same steps, and a batch of them runs the record's samples once for all,
        measured in `benchmarks/posterior.md`); its warmup then `"chains"` on a CPU, one unit
        a call (:func:`warmup_vectorized`).
    - `continuations`: at most this many further rounds for the units whose chains missed
        R-hat <= `RHAT_MAX`, bulk or tail ESS >= `ESS_MIN`, or diverged; what still misses is
        warned about (`Posterior.rounds` says how many rounds each unit took). NUTS: round r
        runs those units' chains again from the mode with 2^r x the warmup and 2^r x the
        draws, every 2^r-th kept (same shape, about 2^r x the effective draws), and a target
        acceptance raised towards `CONTINUED_TARGET` where a unit diverged. ChEES: round r
        extends those units' chains to 2^r x the draws, every 2^r-th kept; a unit that
        diverged is warmed up again from the mode as NUTS's are. 0: no continuation.
    - `thin`: keep every `thin`-th draw of `thin` x `draws` (the continuations set it).
    - `gradient`: how the residuals are differentiated: `"reverse"` or `"forward"` (their
        Jacobian by `jax.jacfwd`, then transposed: cheaper through a sequential integration,
        e.g. the dynamic models). `None` (default): forward mode for a dynamic model and
        reverse mode for a static one (:meth:`for_model`).
    - `kernel`: how the chains move: :class:`NUTS` (default) or :class:`ChEES`.
    """

    draws: int | None = eqx.field(static=True, default=None)
    chains: int | None = eqx.field(static=True, default=None)
    warmup: int | None = eqx.field(static=True, default=None)
    target_accept: float | None = eqx.field(static=True, default=None)
    max_doublings: int = eqx.field(static=True, default=10)
    dense_mass: bool = eqx.field(static=True, default=True)
    vectorize: bool | str | None = eqx.field(static=True, default=None)
    gradient: str | None = eqx.field(static=True, default=None)
    continuations: int = eqx.field(static=True, default=CONTINUATIONS)
    thin: int = eqx.field(static=True, default=1)
    kernel: AbstractKernel = eqx.field(static=True, default=NUTS())

    def __post_init__(self):
        # the counts not given are the kernel's (one that is no kernel is refused by `check`)
        kernel = self.kernel if isinstance(self.kernel, AbstractKernel) else NUTS()
        for name, default in (("draws", kernel.DRAWS), ("chains", kernel.CHAINS),
                              ("warmup", kernel.WARMUP)):
            if getattr(self, name) is None:
                setattr(self, name, default)

    def for_model(self, dynamic: bool) -> Sampler:
        """Self with `gradient` and `target_accept` chosen where they are None: `"forward"`
        for a dynamic model (one sequential integration, which reverse mode stores and
        replays), `"reverse"` for a static one; the kernel's target acceptance for the
        model's kind."""
        return dataclasses.replace(
            self, gradient=self.gradient or ("forward" if dynamic else "reverse"),
            target_accept=self.kernel.target_accept(dynamic) if self.target_accept is None
            else self.target_accept)

    @property
    def lockstep(self) -> bool:
        """Whether the kernel moves all chains of a page in lockstep (:class:`ChEES`)."""
        return isinstance(self.kernel, ChEES)

    def continued(self, round_: int, diverged: bool) -> Sampler:
        """The settings of continuation round `round_` (>= 1): 2^r x the warmup, the same kept
        draws thinned from 2^r x as many; where the unit diverged, the target acceptance moved
        towards 1, its distance to 1 divided by 4 per round (0.9 -> 0.975 -> 0.994), at most
        `CONTINUED_TARGET`: a curved posterior's divergences go only with a small step."""
        f = 2 ** int(round_)
        target = self.target_accept
        if diverged and target is not None:
            target = min(max(target, 1.0 - (1.0 - target) / 4.0 ** int(round_)),
                         max(target, CONTINUED_TARGET))
        return dataclasses.replace(self, warmup=self.warmup * f, thin=self.thin * f,
                                   target_accept=target)

    def check(self) -> Sampler:
        """Self, checked: :class:`mrjax.InputError` for a non-positive count, a target outside
        (0, 1) or a kernel that is not one."""
        if isinstance(self.continuations, bool) or not isinstance(
                self.continuations, (int, np.integer)) or self.continuations < 0:
            raise InputError(f"continuations must be an integer >= 0, got "
                             f"{self.continuations!r}")
        for name in ("draws", "chains", "warmup", "max_doublings", "thin"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise InputError(f"{name} must be a positive integer, got {v!r}")
        if not isinstance(self.kernel, AbstractKernel):
            raise InputError(f"kernel must be mrjax.bayes.NUTS() or mrjax.bayes.ChEES(), got "
                             f"{self.kernel!r}")
        if self.lockstep and self.chains < 2:
            raise InputError(f"ChEES needs at least 2 chains per unit, got {self.chains}")
        if self.target_accept is not None and not 0.0 < float(self.target_accept) < 1.0:
            raise InputError(f"target_accept must be in (0, 1), got {self.target_accept!r}")
        if self.vectorize not in (None, True, False, *VECTORIZE):
            raise InputError(f"vectorize must be None, True, False or one of "
                             f"{', '.join(VECTORIZE)}, got {self.vectorize!r}")
        if self.gradient not in (None, "reverse", "forward"):
            raise InputError(f"gradient must be None, 'reverse' or 'forward', got "
                             f"{self.gradient!r}")
        return self

# ------------------------------------------------------------------------------ progress
#: The progress bar of the running sample, advanced from inside the compiled program.
BAR: list[Any] = [None]


def _tick_host(n):
    bar = BAR[0]
    if bar is not None:
        bar.update(int(np.ravel(n)[0]))


def tick(n):
    """Advance the progress bar by `n` steps of one chain: a `jax.debug.callback` (an effect:
    never removed as dead code; under vmap and on each device it runs once per chain)."""
    jax.debug.callback(_tick_host, n)


def vectorized(sampler: Sampler) -> str:
    """What is vmapped, `"all"`, `"chains"` or `"none"` (see `Sampler.vectorize`)."""
    v = sampler.vectorize
    if v is None:
        if jax.default_backend() != "cpu":
            return "all"
        if sampler.lockstep:  # a unit's chains always move together
            return "all" if sampler.gradient == "forward" else "chains"
        return "chains" if sampler.gradient == "forward" else "none"
    return {True: "all", False: "none"}.get(v, v) if isinstance(v, bool) else str(v)


def warmup_vectorized(sampler: Sampler) -> str:
    """What ChEES's warmup vmaps (:func:`vectorized`), except by default (`vectorize` None) on
    a CPU, where the units of a page are mapped, their chains vmapped (`"chains"`): a unit's
    trajectory length is found during the warmup, so a vmapped page cannot be made of units
    of similar length and would advance at its longest at every step (the draws vmap pages
    of units of similar adapted length; `benchmarks/posterior.md`)."""
    if sampler.vectorize is None and jax.default_backend() == "cpu" and sampler.lockstep:
        return "chains"
    return vectorized(sampler)


def chain_devices(sampler: Sampler) -> int:
    """Over how many devices a unit's chains are spread (1: none): with several CPU devices
    (`jax.config.update("jax_num_cpu_devices", n)` or `JAX_NUM_CPU_DEVICES=n` before JAX
    starts; the `mrjax` command sets it for a posterior) and `vectorize` other than `"all"`,
    the most that divide `chains`; each device runs its share of the chains on its own core,
    its trajectories no longer waiting for the longest of a vmapped batch."""
    n = jax.local_device_count()
    if n < 2 or jax.default_backend() != "cpu" or vectorized(sampler) == "all":
        return 1
    return max(d for d in range(1, min(n, sampler.chains) + 1) if sampler.chains % d == 0)
