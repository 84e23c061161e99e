"""The tachometer's scale from a recording: the ``speed_scale`` under which the creep
estimator's model explains how the vehicle ran on the published track best.

Why: the creep estimator's model takes the train's speed from ``rail/speed``, and its creep
factor moves by 6-9 times the speed's relative error (development cars of the rail family,
pattern C with the track published; docs/methods/creep_estimator.md, "The tachometer's
scale"). A tachometer's scale drifts as its wheel wears and jumps when the wheel is
re-profiled; the nodes multiply the published speed by their ``speed_scale`` parameter
(``rail_imu_inputs.SpeedInput``), and this tool learns it.

How: the lateral-states estimator (pattern A-C, full car model, the track published) is run
over the recording by the offline engine, as the node would run it, once per scale of a grid
around the configured one. Each sample's log-likelihood of the vehicle channels given its track
rows (``CreepEkf.vehicle_likelihood``, on its first filtering) is summed from ``skip_s`` on,
and a parabola fitted to the sums near their maximum gives the scale and, from its curvature,
a spread. The speed is identifiable there because the full model reads its rear bogie's track
from the front pair's a car length earlier, where the car stood by the speed: a wrong speed
misplaces that track under the rear bogie. Two things would bias it, and are kept out: the
track rows' own likelihood, which measures how well the track spectrum's model at a speed
predicts the published track and favours a slower car (0.13-0.47 % on the development cars);
and a model not built at the scale's speed (within ``speed_tolerance_mps`` of the configured
speed the filter steps that model to first order, which favours the configured speed): every
run here rebuilds beyond ``CALIBRATION_SPEED_TOLERANCE_MPS``. Without a published track, or
with a pattern-D (IMU) estimator, whose likelihood given the track still peaks some 0.35 %
low (its track delays are Pade cascades; car 1001, exact track), the tool refuses.

Measured (benchmarks/creep_speed_scale.py, 6 development cars, tachometers 0.4-1.3 % off, 30 s
at constant speed): the scale within 0.02 % with the exact track, 0.063 % with a 0.1 mm map,
0.15 % with a 0.3 mm map; c's rms error then that of the true speed. A recording at steady speed
is best: while the speed changes, every 0.01 m/s is a new model (not measured here).

Run: ``ros2 run rail_monitor_ros rail_speed_scale BAG [--params PARAMS_FILE ...]
[--node creep_estimator] [--span 0.02] [--step 0.0025] [--skip-s 5] [--out FILE]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math
from pathlib import Path
import sys
import tempfile
from typing import Any

import numpy as np
import yaml

from rail_monitor_ros.core.creep_ekf import CreepEkf
from rail_monitor_ros.processing.creep_estimator import CreepEstimatorProcessor
from rail_monitor_ros.processing.rail_imu_inputs import SPEED
from vehicle_monitor_common.bag_io import BagError, bag_topics
from vehicle_monitor_common.graph_spec import load_graph
from vehicle_monitor_common.offline_engine import EngineNode, OfflineGraph
from vehicle_monitor_common.parameters import ConfigurationError

#: Grid points whose summed log-likelihood is within this of the best are fitted (nats).
FIT_WINDOW_NATS = 150.0
#: Each run's models are rebuilt when the speed moves this far, m/s (the shipped 0.5 steps a
#: model built at the configured speed to the scale's, and favours the configured speed).
CALIBRATION_SPEED_TOLERANCE_MPS = 0.01
#: The parabola must explain this share of the fitted points' variance (R^2): sums that are
#: rugged around their maximum (a recording with little of the track under the rear bogie, a
#: map too coarse) would give a scale error passed off as a correction.
MIN_FIT_R2 = 0.9

TRACK = 'rail/track_irregularity'


@dataclass(frozen=True)
class ScaleFit:
    """The likelihood over the grid and the scale fitted to it.

    Attributes:
        scales: the grid of ``speed_scale`` values run.
        log_likelihoods: summed log-likelihood of each (nats).
        samples: samples summed (after ``skip_s``, with an update).
        scale: the fitted scale (NaN if ``problem``).
        std: its spread from the parabola's curvature, 1 / sqrt(-2 a) (the likelihood's
            Cramer-Rao spread, if the model were exact; NaN if ``problem``).
        problem: why no scale is given ('' if one is).
    """

    scales: np.ndarray
    log_likelihoods: np.ndarray
    samples: int
    scale: float
    std: float
    problem: str


def fit_scale(scales: np.ndarray | Sequence[float], log_likelihoods: Sequence[float],
              samples: int, window_nats: float = FIT_WINDOW_NATS) -> ScaleFit:
    """The parabola through the grid points near the best one, and its vertex.

    No scale is given when the best point is at an edge of the grid (the maximum may lie
    beyond it), fewer than three points are within ``window_nats`` of it, the parabola does
    not open downwards or explains less than ``MIN_FIT_R2`` of their variance.
    """
    x = np.asarray(scales, dtype=float)
    ll = np.asarray(log_likelihoods, dtype=float)

    def failed(problem: str) -> ScaleFit:
        return ScaleFit(x, ll, samples, math.nan, math.nan, problem)

    if not np.all(np.isfinite(ll)):
        return failed('a run of the grid gave no likelihood')
    best = int(np.argmax(ll))
    if best in (0, x.size - 1):
        return failed(f'the likelihood is highest at the edge of the grid ({x[best]:.5f}): '
                      'widen --span')
    near = ll >= ll[best] - window_nats
    if np.count_nonzero(near) < 3:
        return failed(f'fewer than 3 grid points within {window_nats:g} nats of the best: '
                      'use a finer --step')
    # In the scale's deviation from the grid's centre, for a well-conditioned fit.
    centre = x[best]
    coefficients = np.polyfit(x[near] - centre, ll[near], 2)
    a, b = coefficients[:2]
    residual = ll[near] - np.polyval(coefficients, x[near] - centre)
    spread = np.sum((ll[near] - ll[near].mean()) ** 2)
    r2 = 1.0 - np.sum(residual ** 2) / spread if spread > 0.0 else 0.0
    if not a < 0.0:
        return failed('the likelihood does not peak (no speed information in the recording: '
                      'a published track is needed)')
    if r2 < MIN_FIT_R2:
        return failed(f'the likelihood is rugged around its maximum (a parabola explains '
                      f'{100 * r2:.0f} % of it): no scale can be read from this recording')
    vertex = centre - b / (2.0 * a)
    if not x[0] < vertex < x[-1]:
        return failed(f'the fitted maximum ({vertex:.5f}) is outside the grid: widen --span')
    return ScaleFit(x, ll, samples, float(vertex), float(1.0 / math.sqrt(-2.0 * a)), '')


def estimator_node(graph: OfflineGraph, name: str) -> EngineNode:
    """The graph's creep estimator of that name (or fully qualified name), checked to be one
    whose likelihood tells the speed.

    Raises:
        ConfigurationError: no such node, not a creep estimator, or one of pattern D or the
            end model (no rear track read from the front's).
    """
    for node in graph.nodes:
        if name in (node.fqn, node.fqn.rsplit('/', 1)[-1]):
            break
    else:
        raise ConfigurationError(f'the graph has no node {name!r}')
    processor = node.processor
    if not isinstance(processor, CreepEstimatorProcessor):
        raise ConfigurationError(f'{node.fqn} is not a creep estimator')
    params = processor.params
    if params.pattern == 'D' or params.model != 'full':
        raise ConfigurationError(
            f'{node.fqn} runs pattern {params.pattern} with the {params.model} model: the '
            'speed is learned from a lateral-states estimator (pattern A-C) of the full model')
    if not processor.node_params.use_speed_input:
        raise ConfigurationError(f'{node.fqn} does not follow rail/speed (use_speed_input)')
    return node


def _summed_log_likelihood(node: EngineNode, bag: Path, skip_s: float) -> tuple[float, int]:
    """Run one node over the recording; its samples' first-pass log-likelihoods summed from
    ``skip_s`` (in samples at the estimator's rate: the filter's start-up is not the speed's)."""
    processor = node.processor
    assert isinstance(processor, CreepEstimatorProcessor)
    ekf: CreepEkf = processor.ekf
    ekf.vehicle_likelihood = True
    skip = round(skip_s * ekf.params.sample_rate_hz)
    filtered = ekf.step
    sums = [0.0, 0, 0]      # log-likelihood, samples with an update, samples seen

    def step(*args: Any, **kwargs: Any) -> Any:
        estimate = filtered(*args, **kwargs)
        sums[2] += 1
        if sums[2] > skip and ekf.sample_log_likelihood != 0.0:
            sums[0] += ekf.sample_log_likelihood
            sums[1] += 1
        return estimate

    # An instance attribute shadows the method for this run's estimator only.
    ekf.step = step  # type: ignore[method-assign]
    OfflineGraph([node]).run(bag)
    return float(sums[0]), int(sums[1])


def learn_speed_scale(bag: Path, graph_file: Path,
                      parameters: Mapping[str, Mapping[str, Any]], node_name: str,
                      span: float = 0.02, step: float = 0.0025, skip_s: float = 5.0,
                      progress: Callable[[str], None] | None = None) -> ScaleFit:
    """The speed scale of a recording (module docstring), on a grid of
    ``configured x (1 + k step)`` for |k step| <= ``span``.

    Raises:
        ConfigurationError: the node cannot learn the speed (:func:`estimator_node`), or the
            recording lacks its speed or track.
        BagError: the recording cannot be read.
    """
    if not 0.0 < step <= span < 0.5:
        raise ConfigurationError(f'need 0 < step <= span < 0.5, got step {step}, span {span}')
    spec = load_graph(graph_file)
    node = estimator_node(OfflineGraph.from_spec(spec, parameters), node_name)
    recorded = bag_topics(bag)
    for topic, what in ((node.topic(SPEED), 'speed'), (node.topic(TRACK), 'track')):
        if topic not in recorded:
            raise ConfigurationError(f'{bag}: no {topic}: the speed is learned from a '
                                     f'recording with the train\'s {what}')
    assert isinstance(node.processor, CreepEstimatorProcessor)
    configured = node.processor.node_params.speed_scale
    steps = round(span / step)
    scales = configured * (1.0 + step * np.arange(-steps, steps + 1))
    values = {**parameters.get(node_name, {}), **parameters.get(node.fqn, {})}
    sums, samples = [], 0
    for i, scale in enumerate(scales):
        run = dict(parameters)
        run[node.fqn] = {**values, 'speed_scale': float(scale),
                         'speed_tolerance_mps': CALIBRATION_SPEED_TOLERANCE_MPS}
        fresh = estimator_node(OfflineGraph.from_spec(spec, run), node.fqn)
        total, samples = _summed_log_likelihood(fresh, bag, skip_s)
        sums.append(total)
        if progress is not None:
            progress(f'scale {scale:.5f}: log-likelihood {total:.1f} over {samples} samples '
                     f'({i + 1}/{scales.size})')
    return fit_scale(scales, sums, samples)


def params_yaml(scale: float) -> str:
    """A ROS params file giving every rail node the scale (the estimators and the suspension
    monitor read the same ``rail/speed``)."""
    return yaml.safe_dump({'/**': {'ros__parameters': {'speed_scale': round(scale, 6)}}},
                          sort_keys=False)


def main(argv: Sequence[str] | None = None) -> int:
    # The command line's only: the rail domain (its graph) and the vehicle's params files come
    # with the evaluation's plotting; the benchmark and the tests import the fit without them.
    from rail_monitor_ros.offline.evaluation import domain
    from vehicle_monitor_common.evaluate_cli import read_vehicle

    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0].strip())
    parser.add_argument('bag', type=Path, help='a rail recording with rail/lateral_states, '
                        'rail/track_irregularity and rail/speed')
    parser.add_argument('--params', action='append', default=[], metavar='PARAMS_FILE',
                        help='the vehicle\'s ROS params files (as the nodes take them)')
    parser.add_argument('--graph', type=Path, default=None,
                        help='graph or launch file (default: the shipped rail graph)')
    parser.add_argument('--node', default='creep_estimator',
                        help='the lateral-states creep estimator (name or full name)')
    parser.add_argument('--span', type=float, default=0.02,
                        help='largest relative deviation from the configured scale tried')
    parser.add_argument('--step', type=float, default=0.0025, help='the grid\'s relative step')
    parser.add_argument('--skip-s', type=float, default=5.0,
                        help='the filter\'s start-up, left out of the likelihood, s')
    parser.add_argument('--out', type=Path, default=None,
                        help='write the result as a ROS params file (speed_scale for every node)')
    args = parser.parse_args(argv)
    rail = domain()
    try:
        with tempfile.TemporaryDirectory(prefix='speed-scale-') as scratch:
            parameters = read_vehicle(args.params).run_parameters(rail, Path(scratch))
            fit = learn_speed_scale(args.bag, args.graph or rail.graph, parameters, args.node,
                                    args.span, args.step, args.skip_s,
                                    lambda line: print(line, flush=True))
    except (ConfigurationError, BagError) as exc:
        print(f'rail_speed_scale: {exc}', file=sys.stderr)
        return 2
    if fit.problem:
        print(f'rail_speed_scale: no scale learned: {fit.problem}', file=sys.stderr)
        return 1
    print(f'speed_scale: {fit.scale:.5f} (spread {fit.std:.5f}, {fit.samples} samples)')
    if args.out is not None:
        args.out.write_text(params_yaml(fit.scale))
        print(f'written to {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
