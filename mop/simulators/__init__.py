"""Learned simulators trained on their simulation error: a model of the plant y = G(u) from its inputs
alone, started from a state an encoder estimates from the first n measured steps, fitted on the free-run
error over subsections of the estimation record (the loss of SUBNET, deep LRU and dynoNet).

mop.simulators.lru: the linear recurrent unit (Orvieto et al. 2023) and its deep stack, with a parallel
scan equal to its step-by-step loop. mop.simulators.fit: the training on the simulation error and the
predictor it gives (a mop Predictor: simulate(traj, context) in the record's units).
"""

from mop.simulators.fit import SimulatorConfig, SimulatorPredictor, fit_simulator, simulator_line
from mop.simulators.lru import LRU, DeepLRU

__all__ = ["LRU", "DeepLRU", "SimulatorConfig", "SimulatorPredictor", "fit_simulator", "simulator_line"]
