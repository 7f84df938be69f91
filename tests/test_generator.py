import pytest

from tsac_bench.model.generator import (
    AAV_TYPES,
    PAPER_SCALES,
    ScenarioGenerator,
    generate,
    parse_scale,
)
from tsac_bench.model.io import instance_to_dict


def test_same_seed_same_instance_other_seed_other_instance():
    assert instance_to_dict(generate("16/40", 7)) == instance_to_dict(generate("16/40", 7))
    assert instance_to_dict(generate("16/40", 7)) != instance_to_dict(generate("16/40", 8))


@pytest.mark.parametrize("scale", PAPER_SCALES)
def test_paper_scales_follow_the_documented_distributions(scale):
    n, m = parse_scale(scale)
    instance = generate(scale, seed=1)
    assert (instance.n_aavs, instance.n_tasks, instance.n_depots) == (n, m, max(2, n // 4))
    assert sum(a.type == 1 for a in instance.aavs) == -(-n // 4)
    for a in instance.aavs:
        assert {k: getattr(a, k) for k in AAV_TYPES[a.type]} == AAV_TYPES[a.type]
        assert (a.x, a.y) in {(d.x, d.y) for d in instance.depots}
    fastest = max(t["speed"] for t in AAV_TYPES.values())
    for t in instance.tasks:
        assert -5000 <= t.x <= 5000 and -5000 <= t.y <= 5000
        assert t.demand in (5, 10, 20, 30, 40, 60)
        assert t.release <= t.t_start <= t.release + 300
        reach = min(instance.dist[instance.depot_node(k), instance.node_index[t.id]]
                    for k in range(instance.n_depots)) / fastest
        assert t.t_end >= t.release + reach + 60  # a fast AAV can make it after the release
        assert t.t_end - t.t_start <= instance.horizon
    assert (instance.horizon, instance.weights) == (3600.0, (100.0, 10.0, 1.0))


def test_dynamic_share_and_events():
    instance = ScenarioGenerator(dynamic_share=1.0, n_events=3).generate(8, 200, seed=0)
    assert all(t.release > 0 for t in instance.tasks)
    assert len({t.release for t in instance.tasks}) <= 3
    static = ScenarioGenerator(dynamic_share=0.0).generate(8, 20, seed=0)
    assert all(t.release == 0 for t in static.tasks)


@pytest.mark.parametrize("text", ["16", "a/b", "0/5", "4/-1"])
def test_bad_scales(text):
    with pytest.raises(ValueError, match="scale"):
        parse_scale(text)
