"""HTTP routes: thin handlers that validate, route to `planner` or the job runner, and store."""
