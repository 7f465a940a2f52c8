"""The L-System engine: parsing, parametric and conditional rules, stochastic choice, seeds."""

import numpy as np
import pytest

from plantdreamer.errors import InputError
from plantdreamer.lsystem.engine import LSystem, Module, Rule, format_string


def derive(axiom, rules, n, seed=0, constants=None):
    return LSystem(axiom, rules, constants).derive(n, np.random.default_rng(seed))


def test_algae_deterministic_growth_gives_fibonacci_lengths():
    rules = [Rule("A", "AB"), Rule("B", "A")]
    lengths = [len(derive("A", rules, n)) for n in range(8)]
    assert lengths == [1, 2, 3, 5, 8, 13, 21, 34]
    assert format_string(derive("A", rules, 3)) == "A B A A B"


def test_parameters_expressions_and_conditions():
    rules = [Rule("A(n, w)", "F(w) A(n+1, w*0.5)", "n < 2"), Rule("A(n, w)", "X(n)", "n >= 2")]
    out = derive("A(0, 8)", rules, 4)
    assert out == [Module("F", (8.0,)), Module("F", (4.0,)), Module("X", (2.0,))]


def test_constants_and_functions_are_visible_to_expressions():
    out = derive("A(1)", [Rule("A(x)", "B(k*twice(x), sqrt(16))")], 1,
                 constants={"k": 3, "twice": lambda v: 2 * v})  # fmt: skip
    assert out == [Module("B", (6.0, 4.0))]


def test_modules_without_matching_rule_or_arity_are_copied():
    out = derive("A(1) A [ + ]", [Rule("A", "B")], 1)
    assert [str(m) for m in out] == ["A(1)", "B", "[", "+", "]"]


def test_empty_successor_deletes_the_module():
    assert derive("A B A", [Rule("A", "")], 1) == [Module("B")]


def test_stochastic_rules_follow_their_probabilities():
    rules = [Rule("A", "X", probability=3.0), Rule("A", "Y", probability=1.0)]
    out = derive("A" * 4000, rules, 1, seed=5)
    share = sum(m.symbol == "X" for m in out) / len(out)
    # Binomial(4000, 0.75): sd = 0.0068; 5 sd either side.
    assert abs(share - 0.75) < 0.035


def test_rand_is_uniform_in_range_and_seeded():
    out = derive("A" * 2000, [Rule("A", "B(rand(100, 160))")], 1, seed=1)
    values = np.array([m.params[0] for m in out])
    assert values.min() >= 100 and values.max() <= 160
    assert abs(values.mean() - 130) < 1.5
    again = derive("A" * 2000, [Rule("A", "B(rand(100, 160))")], 1, seed=1)
    other = derive("A" * 2000, [Rule("A", "B(rand(100, 160))")], 1, seed=2)
    assert out == again
    assert out != other


def test_randint_is_inclusive():
    out = derive("A" * 500, [Rule("A", "B(randint(1, 3))")], 1)
    assert {m.params[0] for m in out} == {1.0, 2.0, 3.0}


def test_rules_without_matching_condition_leave_the_module():
    assert derive("A(5)", [Rule("A(n)", "B", "n < 3")], 1) == [Module("A", (5.0,))]


@pytest.mark.parametrize(
    ("rule", "message"),
    [
        (Rule("A(n)", "B(m)"), "unknown name"),
        (Rule("A(n)", "B(n.real)"), "not allowed"),
        (Rule("A(n)", "B(__import__('os'))"), "numeric|unknown name"),
        (Rule("A(n)", "B((n)"), "unbalanced"),
        (Rule("A(n)", "B('x')"), "numeric"),
        (Rule("A(n) B", "C"), "one module"),
        (Rule("A(1)", "C"), "formal parameter"),
        (Rule("A", "B", probability=0.0), "probability"),
        (Rule("A(n)", "B(n +)"), "invalid expression"),
    ],
)
def test_bad_grammars_fail_early_with_input_error(rule, message):
    with pytest.raises(InputError, match=message):
        LSystem("A(1)", [rule])


def test_non_finite_parameters_are_rejected():
    with pytest.raises(InputError, match="inf"):
        derive("A(1)", [Rule("A(n)", "B(n * 1e308 * 10)")], 1)


def test_division_by_zero_is_an_input_error():
    with pytest.raises(InputError, match="failed"):
        derive("A(0)", [Rule("A(n)", "B(1/n)")], 1)


def test_runaway_growth_fails_clearly(monkeypatch):
    import plantdreamer.lsystem.engine as engine

    monkeypatch.setattr(engine, "MAX_MODULES", 1000)
    with pytest.raises(InputError, match="grew past"):
        derive("A", [Rule("A", "AA")], 20)
