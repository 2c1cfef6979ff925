"""Evaluation: text–motion evaluators, the field's metrics with 95% intervals, physics and control errors.

- metrics: FID, R-precision (batches of 32), MM-Dist, Diversity, MultiModality, replication intervals, AITS
- physics: foot-skating ratio (GMD definition), PhysDiff-style penetration / floating / sliding
- control: trajectory-control errors (Traj. err, Loc. err at 50 cm, Avg. err)
- guo, word_vectorizer: the published Guo et al. evaluator (weight-compatible) and its GloVe/POS inputs
- evaluator: StableMo's own contrastive evaluator (LightningModule, configs/evaluator_*.yaml)
- command: `stablemo evaluate`
"""
