"""Cases as jobs: what a job gets (`rows.CaseTask`) and gives back (`rows.CaseRow`), the job
itself (`case.process_case`, one case through the pipeline in whatever process or cluster job
runs it) and the driver that sends jobs with work left to one of the engine's executors
(`driver.run_cases`). `endopipe batch` sends its cases through it and a recording its windows;
neither owns it.

Nothing is imported here: the command line reads `options` at start-up and stays fast.
"""
