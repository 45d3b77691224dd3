"""What the tests and the benchmarks both run undertow on: robots, the seed paper's printed
equations, cases at the numerical edges, the generated task suites (`testbed.suites`), the
service in a process of its own and the faults it must survive. Tests and benchmarks import
this package, never each other."""
