"""Explore a trained run in the browser: a slider per design variable, the OLED objective of every predictor.

  python -m experiments.explore --workdir runs/cpu                 # then open http://127.0.0.1:8050/
  python -m experiments.explore --workdir runs/family --port 8060  # a scene family: a slider per scene parameter
  python -m experiments.explore --workdir RUN --no_mgn             # baselines only (no model load, quick start)

Needs the explore extra: pip install -e ".[explore]". Any run directory with a config.json and its
training data works: with a checkpoint the run's MGN is the default predictor; without one (a
regression-only run) give --no_mgn and kriging is (a run without a checkpoint is refused otherwise).
The page shows the training box (out-of-box designs are flagged), the
objective of the MGN and of every baseline (kriging with its GP std), the von Mises field on the deformed
section at a chosen frame (log colour scale, axes in mm), the OLED layer on its own scale, the OLED reading
and the ball over time, and a "check with the solver" button (the built-in solver at the design, its truth
and the error overlaid). The library is pcmgn_jax.explore; this module parses flags and serves.
"""
import sys
from dataclasses import dataclass
from typing import ClassVar, Literal

from pcmgn_jax import cli


@dataclass(frozen=True)
class ExploreArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"port": (0, True, 65535)}
    workdir: str                                   # run directory (config.json; checkpoints for the MGN)
    host: str = "127.0.0.1"                        # address to bind (127.0.0.1: this machine only)
    port: int = 8050                               # port of the page
    which: Literal["best", "periodic"] = "best"    # MGN checkpoint
    mgn: bool = True                               # load the run's MGN (--no_mgn: baselines only)
    # the MGN's ± (a GP of its residuals on the training scenes; one rollout per training scene at load)
    mgn_spread: bool = False
    objective: Literal["area_mean", "node_mean", "disc_mean", "peak"] = "area_mean"  # reading (docs/design.md §8)


def main(argv=None) -> int:
    args = cli.parse(ExploreArgs, argv, description=__doc__, prog="python -m experiments.explore")
    no_mgn = None if args.mgn else "--no_mgn (the page has no MGN)"
    cli.refuse_inapplicable(cli.given_flags(sys.argv[1:] if argv is None else argv),
                            {"which": no_mgn, "mgn_spread": no_mgn})
    from pcmgn_jax.mgn.checkpoint import MissingRun, require_run
    try:   # before anything starts: a bad path or a run without a checkpoint is one line (status 2)
        require_run(args.workdir, checkpoint=args.mgn)
    except MissingRun as err:
        raise MissingRun(f"{err}" + (" (or explore its baselines only: --no_mgn)" if args.mgn else "")) from None
    try:
        import dash  # noqa: F401
    except ImportError:
        raise ValueError('the explorer needs Dash: pip install -e ".[explore]"') from None
    import socket
    with socket.socket() as probe:   # say a taken port before the run is loaded, not after
        try:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)   # as the server will
            probe.bind((args.host, args.port))
        except OSError as err:
            raise ValueError(f"cannot serve on {args.host}:{args.port}: {err} (choose another --port)") from None
    from pcmgn_jax.explore import Explorer
    from pcmgn_jax.explore.app import serve
    serve(Explorer(args.workdir, which=args.which, mgn=args.mgn, reading=args.objective,
                   mgn_spread=args.mgn_spread), host=args.host,
          port=args.port)
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
