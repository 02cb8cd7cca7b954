"""The learned reasoning VLA ("pi0-reason" at CPU scale) and its non-reasoning twin.

- `tokenizer`: a byte-level BPE trained on the project's own text, with <think>/<act> specials;
- `model`: conv image encoder + transformer prefix + causal reasoning decoder + flow-matching
  action expert + think head (`VLAConfig`, `VLAModel`);
- `preprocess`: images to the model's resolution, texts to padded ids (shared by training and
  inference);
- `checkpoint`: safetensors + config + tokenizer + manifest, checked on load; 16-bit export;
- `locate`: shipped checkpoints and a checkpoint's identity (no torch);
- `policy`: `VLAPolicy` (the `ReasoningPolicy` seam) and the registry factory ``vla``.

Training lives in `seal.train.vla`; ``seal bench vla`` in `seal.benchmarks.vla`.
"""
