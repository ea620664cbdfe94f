"""The numerical methods behind one backend interface (backends/): the interior point
(interior/), the projected Newton method, IPOPT through CasADi, L-BFGS; the solvers built per
structure (nlp_cache) and the strategy that picks among them."""
