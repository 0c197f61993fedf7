"""Monte-Carlo studies at scale: dispersion files, runs reproducible from ``(seed, run)``,
batched compiled rollouts (CasADi ``map`` with threads) over chunks of runs, Dask scale-out,
resumable chunk files, and statistics (per-run table, envelopes, exceedance probabilities with
Wilson intervals, figures, a Markdown summary).

Typical use::

    from uavdyn.airframes import load_airframe
    from uavdyn.montecarlo import build_spec, load_dispersions, run_study

    af = load_airframe("aerosonde")
    spec = build_spec(af, load_dispersions("aerosonde_pm15", af),
                      runs=1000, duration=60.0, dt=0.01, mission="doublet")
    result = run_study(spec, out="results/mc", threads=2)
    result.table["max_abs_pitch_deg"], result.exceedance, result.envelopes.band("alpha")

Dask (``pip install 'dask[distributed]'``) is imported only for ``workers > 1`` or a
``scheduler``.
"""

from uavdyn.montecarlo.batch import SIGNALS, STAT_NAMES, batch_function, gust_step, run_function
from uavdyn.montecarlo.chunks import RESULT_COLUMNS, ChunkResult, evaluate_chunk
from uavdyn.montecarlo.commands import command_deviations, input_names
from uavdyn.montecarlo.dispersions import (
    DispersionError,
    Dispersions,
    Distribution,
    RunDraw,
    load_dispersions,
    parse_dispersions,
)
from uavdyn.montecarlo.errors import MonteCarloError
from uavdyn.montecarlo.spec import StudySpec, build_spec, resolve_limits
from uavdyn.montecarlo.statistics import (
    Envelopes,
    Exceedance,
    RunTable,
    envelopes,
    exceedances,
    wilson_interval,
)
from uavdyn.montecarlo.study import MonteCarloResult, run_study

__all__ = ["SIGNALS", "STAT_NAMES", "batch_function", "gust_step", "run_function",
           "RESULT_COLUMNS", "ChunkResult", "evaluate_chunk", "DispersionError", "Dispersions",
           "Distribution", "RunDraw", "load_dispersions", "parse_dispersions",
           "MonteCarloError", "StudySpec", "build_spec", "command_deviations", "input_names",
           "resolve_limits", "Envelopes", "Exceedance", "RunTable", "envelopes", "exceedances",
           "wilson_interval", "MonteCarloResult", "run_study"]
