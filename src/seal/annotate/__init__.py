"""Reasoning annotation: demonstration videos -> plans and critical moments -> per-chunk labels.

`pipeline.annotate_dataset` is the entry point (`seal annotate` on the command line);
`loader.AnnotatedDataset` reads the result back; `quality.quality_report` compares any
annotator with the expert's recorded ground truth.
"""
