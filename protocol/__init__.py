"""Host-board protocol: frames, messages, reliable link, transports, legacy line codec."""

# On-board learning's messages (issue 34) live in their own module and register themselves in
# the message tables of ``messages`` when imported: importing the package registers them.
from snan_hil.protocol import learn_messages as _learn_messages  # noqa: E402,F401
