from rbfn.growth import grow, growth_schedule


def test_schedule():
    assert growth_schedule(10, 2.0, 80) == [10, 20, 40, 80]
    assert growth_schedule(10, 2.0, 50) == [10, 20, 40, 50]
    assert growth_schedule(0, 2.0, 40) == [40]
    assert growth_schedule(10, 2.0, 5) == [5]
    assert growth_schedule(3, 1.1, 6) == [3, 4, 5, 6]


def test_growth_stops_at_goal():
    tried = []

    def fit_at(m):
        tried.append(m)
        return f"net{m}", 1.0 / m

    result, curve = grow(fit_at, [10, 20, 40, 80], goal=0.03)
    assert result == "net40" and tried == [10, 20, 40]
    assert curve == [(10, 0.1), (20, 0.05), (40, 0.025)]


def test_growth_runs_to_max_when_goal_unmet():
    result, curve = grow(lambda m: (m, 1.0), [1, 2, 3], goal=0.0)
    assert result == 3 and len(curve) == 3
