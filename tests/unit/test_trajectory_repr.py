"""``repr(Trajectory)``: one short line, whatever the number of frames and particles."""

import numpy as np

from springsim import ModelBuilder, simulate
from springsim.integrators import make_integrator
from springsim.run.driver import Trajectory


def test_trajectory_repr_is_one_short_line():
    """30 steps of a 24 x 24 cloth repr as counts and the time span, not as the arrays of every frame."""
    b = ModelBuilder()
    b.add_cloth_grid(nx=24, ny=24, stiffness=1e3, pin=["top"])
    model = b.finalize()
    traj = simulate(model, make_integrator("linearized_implicit", model), 0.5 / 30, 30)
    assert repr(traj) == "Trajectory(frames=31, particles=576, t=[0, 0.5] s, steps=30, failed_steps=0)"


def test_trajectory_repr_of_an_empty_trajectory():
    """A trajectory with no frames (made by hand) still has a one-line repr."""
    empty = Trajectory(t=np.zeros(0), q=np.zeros((0, 5, 3)), qd=np.zeros((0, 5, 3)))
    assert repr(empty) == "Trajectory(frames=0, particles=5, t=[] s, steps=0, failed_steps=0)"
