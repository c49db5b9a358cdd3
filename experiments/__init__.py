"""Experiment families over the stage chain, one folder each holding its stage, report and artifact code: `study`
(held-out error against the amount of training motion), `tradeoff` (every way to the high-res cloth: error against
ms per frame), `multi` (one network for several garments against each garment's own). They read the chain's
artifacts through `pipeline.artifacts` and stand on `pipeline.core`, as the stages do; no stage imports them."""
