"""The points-to-map network: model, Lightning module, training, export and evaluation.

* :mod:`patternshop_nn.networks` — the dual-branch U-Net generator and the PatchGAN discriminator;
* :mod:`patternshop_nn.module` — the conditional GAN as a LightningModule;
* :mod:`patternshop_nn.data` — pair folders as training and validation tensors;
* :mod:`patternshop_nn.train` — the training entry point behind ``python train.py`` (Hydra);
* :mod:`patternshop_nn.baselines` — KDE and palette-decoding baselines, validation metrics;
* :mod:`patternshop_nn.onnx_export` — export of the generator to ONNX with its metadata;
* :mod:`patternshop_nn.evaluate`, :mod:`patternshop_nn.ood` — held-out and out-of-distribution evaluation.

Inference runs without torch, on ONNX Runtime (:mod:`export.runtime`); the shipped model and its
provenance are in ``patternshop_nn/assets``.
"""
