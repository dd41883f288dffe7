"""How long a test waits for something that must happen.

Every wait in the node tests returns as soon as its event happens (a message, a service, an
exit); this ceiling only decides when a test gives up on a node that hangs. With two other
copies of the suite running on the same 2 cores a node's start-up alone took over 60 s, so
the ceiling is far above any healthy wait: a passing test never reaches it.
"""

#: Ceiling (s) of a wait for an event that must happen.
EVENT_S = 300.0
