"""The headroom of look-ahead distillation (issue 17): the J of the one-step look-ahead that
the rollout labels encode (``LookAheadSelection``: in every state, label the candidate
actions by finishing the game with HOCF, take the best), against HOCF's own game, on static
t = 0 games of the first instances of ``instances/paper-mc/``. Run by hand:

    python benchmarks/tsac_lookahead.py --scale 16/40 --instances 5 [--candidates 8] [--rollouts 1]

``--candidates`` is how many actions are labelled per state (HOCF's choice always among
them, the others drawn uniformly; the training's form); without it every valid action is.
The look-ahead plays with method seed 0 (it also draws its rollout seeds from the engine's
generator, so its AAV orders differ from HOCF's game of seed 0). HOCF's J varies much with
the AAV orders (at 8/20 seed 0 of one instance 32 to 114 over 20 seeds), so HOCF is given
as its game of seed 0 and as its mean over seeds 0 .. ``--hocf-seeds`` - 1. Prints one line
per instance and the means.
"""

from __future__ import annotations

import argparse
import statistics
import time

from paper_reproduction import instance_files

from tsac_bench.model.io import read_instance
from tsac_bench.planning import PlanningState, make_allocator
from tsac_bench.solvers.ocf.engine import C_MAX, K_MAX, CoalitionGame, sample_rng
from tsac_bench.solvers.tsac.sac import LookAheadSelection, RolloutWorkers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", required=True)
    parser.add_argument("--instances", type=int, default=5)
    parser.add_argument("--candidates", type=int, default=None)
    parser.add_argument("--rollouts", type=int, default=1)
    parser.add_argument("--hocf-seeds", type=int, default=10)
    parser.add_argument("--workers", type=int, default=1,
                        help="processes for the rollouts (the same results, less wall time)")
    args = parser.parse_args()
    workers = RolloutWorkers(args.workers) if args.workers > 1 else None
    hocf = make_allocator("hocf")
    rows = []
    for path in instance_files(args.scale, args.instances):
        state = PlanningState.static(read_instance(path))
        hocf_costs = []
        for seed in range(args.hocf_seeds):
            game = CoalitionGame(state, state.base_routes())
            game.run(hocf.rule(state), sample_rng(seed, 0), k_max=K_MAX, c_max=C_MAX)
            hocf_costs.append(game.cost)
        began = time.perf_counter()
        game = CoalitionGame(state, state.base_routes())
        game.run(LookAheadSelection(hocf.rule(state), candidates=args.candidates,
                                    rollouts=args.rollouts, workers=workers),
                 sample_rng(0, 0), k_max=K_MAX, c_max=C_MAX)
        row = (hocf_costs[0], statistics.fmean(hocf_costs), game.cost)
        rows.append(row)
        print(f"{args.scale} {path.stem}: J(HOCF seed 0) {row[0]:.3f}, mean J(HOCF) "
              f"{row[1]:.3f}, J(look-ahead) {row[2]:.3f} "
              f"({100 * (row[1] - row[2]) / row[1]:+.1f} % vs the mean), "
              f"{len(game.decisions)} decisions, {time.perf_counter() - began:.0f} s",
              flush=True)
    seed0, mean, ahead = (statistics.fmean(r[i] for r in rows) for i in range(3))
    form = "every valid action" if args.candidates is None else (
        f"HOCF's choice + up to {args.candidates - 1} drawn")
    print(f"{args.scale}, {len(rows)} instances, labelled: {form}, {args.rollouts} rollout(s):"
          f" mean J: HOCF seed 0 {seed0:.3f}, HOCF over {args.hocf_seeds} seeds {mean:.3f},"
          f" look-ahead {ahead:.3f}: {100 * (seed0 - ahead) / seed0:+.1f} % vs HOCF seed 0,"
          f" {100 * (mean - ahead) / mean:+.1f} % vs HOCF's seed mean (positive = cheaper);"
          f" below HOCF's seed mean on {sum(r[2] < r[1] for r in rows)}/{len(rows)}")
    if workers is not None:
        workers.close()

if __name__ == "__main__":
    main()
