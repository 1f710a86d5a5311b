"""Rotor fault diagnosis from the identified model (pure numpy, no ROS).

observer (super-twisting), residuals (wrench residual and rotor signatures), detection (adaptive
threshold, isolation, effectiveness), diagnoser (the chain and its words), monitor (the identifier
node's logic), record (what the node keeps on disk), campaign (simulated fault campaigns).
"""
