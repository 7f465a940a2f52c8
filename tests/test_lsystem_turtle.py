"""The 3D turtle: moves, rotations, branches, tropism and organ insertion."""

import numpy as np
import pytest

from plantdreamer.errors import InputError
from plantdreamer.lsystem.engine import LSystem
from plantdreamer.lsystem.turtle import TurtleConfig, interpret


def run(string, **config):
    modules = LSystem(string, []).derive(0, np.random.default_rng(0))
    return interpret(modules, TurtleConfig(**config))


def tip(skeleton, chain=0):
    return skeleton.chains[chain].points[-1]


def test_forward_draws_up_from_the_origin():
    sk = run("F(1)", max_step=0.25)
    assert len(sk.chains) == 1
    np.testing.assert_allclose(sk.chains[0].points[:, 2], [0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(sk.chains[0].points[:, :2], 0, atol=1e-12)


def test_frame_is_right_handed_and_turns_follow_the_documented_directions():
    # Initial frame: H = +z, L = +y, U = H x L = -x.
    sk = run("[ +(90) F(1) ] [ -(90) F(1) ] [ &(90) F(1) ] [ ^(90) F(1) ]", max_step=1)
    np.testing.assert_allclose(tip(sk, 0), [0, 1, 0], atol=1e-12)  # left: towards L
    np.testing.assert_allclose(tip(sk, 1), [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(tip(sk, 2), [1, 0, 0], atol=1e-12)  # pitch down: towards -U
    np.testing.assert_allclose(tip(sk, 3), [-1, 0, 0], atol=1e-12)


def test_roll_then_turn_and_turn_around():
    sk = run("/(90) +(90) F(1)", max_step=1)
    # Rolling right by 90 degrees takes L to -U (+x), so a left turn then heads to +x.
    np.testing.assert_allclose(tip(sk), [1, 0, 0], atol=1e-12)
    sk = run("&(90) | F(1)", max_step=1)
    np.testing.assert_allclose(tip(sk), [-1, 0, 0], atol=1e-12)


def test_branches_return_to_the_saved_state_and_continue_the_parent_chain():
    sk = run("F(1) [ +(90) F(1) ] F(1)", max_step=1)
    assert len(sk.chains) == 2
    np.testing.assert_allclose(sk.chains[0].points, [[0, 0, 0], [0, 0, 1], [0, 0, 2]], atol=1e-12)
    assert sk.chains[1].parent == 0
    np.testing.assert_allclose(sk.chains[1].points[0], [0, 0, 1])


def test_move_without_drawing_breaks_the_stem():
    sk = run("F(1) f(1) F(1)", max_step=1)
    assert len(sk.chains) == 2
    np.testing.assert_allclose(sk.chains[1].points[0], [0, 0, 2])


def test_width_is_recorded_per_point():
    sk = run("!(0.01) F(1) !(0.005) F(1)", max_step=1)
    np.testing.assert_allclose(sk.chains[0].radii, [0.01, 0.01, 0.005])


def test_gravity_tropism_bends_a_horizontal_stem_down_and_negative_bends_it_up():
    down = run("&(90) t(2) F(0.5)", max_step=0.01)
    up = run("&(90) t(-2) F(0.5)", max_step=0.01)
    straight = run("&(90) F(0.5)", max_step=0.01)
    assert tip(down)[2] < -0.05
    assert tip(up)[2] > 0.05
    assert abs(tip(straight)[2]) < 1e-12
    # Bending is per metre of stem, not per module: splitting the move changes little.
    split = run("&(90) t(2) F(0.25) F(0.25)", max_step=0.01)
    np.testing.assert_allclose(tip(split), tip(down), atol=1e-9)


def test_organs_record_their_frame_and_parent_chain():
    sk = run("F(1) [ &(90) F(0.5) $ L(0.1, 0.5) ] L(0.2)", max_step=1)
    assert [o.symbol for o in sk.organs] == ["L", "L"]
    leaf = sk.organs[0]
    assert leaf.params == (0.1, 0.5)
    assert leaf.chain == 1
    assert sk.organs[1].chain == 0
    np.testing.assert_allclose(leaf.position, [0.5, 0, 1], atol=1e-12)
    frame = np.array([leaf.heading, leaf.left, leaf.up])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.cross(leaf.heading, leaf.left), leaf.up, atol=1e-12)
    assert leaf.up[2] > 0.99  # $ levelled the frame: the blade's top faces the sky


def test_elevation_command_sets_the_heading_angle_and_levels():
    sk = run("&(30) /(77) E(-20) L(1)")
    organ = sk.organs[0]
    assert np.degrees(np.arcsin(organ.heading[2])) == pytest.approx(-20)
    assert abs(organ.left[2]) < 1e-12
    assert organ.up[2] > 0


@pytest.mark.parametrize("string", ["[ F(1)", "F(1) ]"])
def test_unbalanced_brackets_fail(string):
    with pytest.raises(InputError, match="unbalanced"):
        run(string)
