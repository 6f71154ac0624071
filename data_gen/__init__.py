"""Data generation: the correlation palette and the network's training pairs.

* palette: :mod:`data_gen.palette` (``python -m data_gen.palette``) builds the
  shipped palette from the corpus of :mod:`data_gen.corpus` (random GMM
  spectra) and :mod:`data_gen.families` (known processes), laid out by
  :mod:`data_gen.embedding`; :mod:`data_gen.palette_table` rebuilds its PCF
  table.
* training pairs: :mod:`data_gen.pairs` (``python -m data_gen.pairs``) draws
  target maps with the dataset makers of :mod:`data_gen.makers` and random
  chroma fields (:mod:`data_gen.chroma`), turns them into points (the
  synthesiser, or the other methods of :mod:`data_gen.stipplers`) and stores
  the pairs as shards (:mod:`data_gen.shards`); :mod:`data_gen.preview` draws a
  contact sheet of them; :mod:`data_gen.standins` writes small stand-ins of the
  real datasets' folder layouts.
* :mod:`data_gen.executor`: where the batch work runs (a local process pool
  or a Dask cluster); :mod:`data_gen.provenance`: commit, versions and Hydra
  config loading shared by these commands.
"""
