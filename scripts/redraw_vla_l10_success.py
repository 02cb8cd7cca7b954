"""Redraw docs/images/vla_l10_success.png from the pooled counts of the 2026-12-02 tables (100 official
starts per method) with the report's own labels, paper columns and plot function. Run from the checkout:
`.venv/bin/python scripts/redraw_vla_l10_success.py`. The run's database was lost with a machine; the counts
are the Average rows of docs/results.md's two 2026-12-02 LIBERO-10 tables."""
from pathlib import Path
from types import SimpleNamespace
from seal.report.data import Cell, MethodInfo
from seal.report.labels import display_name
from seal.report.paper import PaperResults, paper_method_for, DEFAULT_TRAINING
from seal.report.plots import success_plot
from seal.report.tables import SuccessTable

runs = [  # (config as `seal eval` stored it, successes of 100)
    (dict(method="base", policy="vla", render="fast", policy_ckpt="009dcdd7fb35"), 8),
    (dict(method="base", policy="vla", render="fast", policy_ckpt="14bb7098169e"), 17),
    (dict(method="value", ckpt="l10_64", policy="vla", render="fast", policy_ckpt="14bb7098169e", k=10), 3),
    (dict(method="seal", policy="vla", render="fast", policy_ckpt="009dcdd7fb35", k=10), 73),
]
paper = PaperResults.load()
methods = [MethodInfo(config_hash=str(i), label=display_name(c), config=c, paper_method=paper_method_for(c))
           for i, (c, _) in enumerate(runs)]
pms = [m.paper_method for m in methods]  # one per method here: pi0_reason, pi0, pi0_vgps, seal
avg = [sum(paper.rate("libero_10", DEFAULT_TRAINING, t, pm) for t in range(10)) / 10 for pm in pms]
table = SuccessTable(suite="libero_10", methods=methods, paper_methods=pms, training=DEFAULT_TRAINING,
                     tasks=list(range(10)), cells={"average": [Cell(n=100, successes=s) for _, s in runs]},
                     paper={"average": avg}, instructions={})
print(success_plot(SimpleNamespace(methods=methods), [table], Path("docs/images/vla_l10_success.png")))
print([(m.label, m.paper_method) for m in methods], avg)
