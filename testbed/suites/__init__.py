"""Generated task suites, the measure of the planner in tests and benchmarks: ordinary
tasks (`ordinary`), hard ones (`hard`) and impossible ones (`impossible`), each drawn from
a seed. The results of the long solves some draws need are
stored as JSON under data/ (`records`); `python -m testbed.suites check` checks them,
`python -m testbed.suites regenerate` solves and writes them again."""
