"""The physics: airframes, effects, the model f(t, x, u), its integrator and its Hamiltonian form."""
