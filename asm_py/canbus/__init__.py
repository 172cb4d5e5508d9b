"""ASM over CAN: the identifier layout, fragmentation, fault injection, DBC generation and bus load."""
