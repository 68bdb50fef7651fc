"""Monte Carlo localization on the acoustic wall map (paper Fig. 1(b)).

Pure functions do the work -- `init_tracked`, `init_global`, `predict` (odometry motion
model), `weigh` (sensor log-likelihood, log-sum-exp), `resample` (systematic), `inject`
(augmented MCL with sensor resetting), `temper_to_ess`, `kld_count` -- and `ParticleFilter` is
a thin stateful object that calls them in order, one sonar block per ``step``, and returns a
`localization.estimate.PoseEstimate`. A bad block raises ``ValueError`` and leaves the state
unchanged; ``state_dict`` / ``ParticleFilter.from_state_dict`` round-trip through ``np.savez``
without pickle (`STATE_FORMAT`). `run_filter` runs a filter over a whole run;
`block_odometry` gives the odometry between consecutive block midpoints; `Steppable` is
anything with the filters' ``step`` (`ParticleFilter`, the grid filter).

Entry points: `FilterConfig` (every parameter, with its unit and measured effect) and
`ParticleFilter`. With the echo sensor model each step also reports an honest status
(`block_fit`: how well the estimate explains the block; `block_status`: converged / uncertain /
lost) and re-localizes on unexplained blocks with poses that explain them (`propose`,
`propose_slots`). A filter started from a tracked pose stays *anchored* until its estimate
`jumped` away from dead reckoning: while anchored, the room's symmetric twins are no rivals
and whole-map proposals carry the prior odds of a kidnap (``FilterConfig.kidnap_prior_nats``).

Notes
-----
Rival hypotheses (``_rivals``: `Rivals`, `RivalParams`, `refine_poses`, `twin_evidence`):
poses far from the estimate that explain the blocks as well or better, found each block among
echo proposals and followed with their evidence, so a filter that settled on the wrong place
(a kidnap along a corridor, a look-alike) does not report ``converged`` there.

Private modules: ``_config`` (`FilterConfig`, JSON round trip included), ``_filter`` (the
algorithm) and ``_rivals``.
"""

from __future__ import annotations

from localization.particle_filter._config import (
    FilterConfig,
)
from localization.particle_filter._filter import (
    STATE_FORMAT,
    ParticleFilter,
    Steppable,
    block_fit,
    block_odometry,
    block_status,
    init_global,
    init_tracked,
    inject,
    jumped,
    kld_count,
    predict,
    propose,
    propose_slots,
    resample,
    run_filter,
    temper_to_ess,
    weigh,
)
from localization.particle_filter._rivals import (
    RivalParams,
    Rivals,
    refine_poses,
    twin_evidence,
)

__all__ = [
    "FilterConfig",
    "ParticleFilter",
    "RivalParams",
    "Rivals",
    "STATE_FORMAT",
    "Steppable",
    "block_fit",
    "block_odometry",
    "block_status",
    "init_global",
    "init_tracked",
    "inject",
    "jumped",
    "kld_count",
    "predict",
    "propose",
    "propose_slots",
    "refine_poses",
    "resample",
    "run_filter",
    "temper_to_ess",
    "twin_evidence",
    "weigh",
]
