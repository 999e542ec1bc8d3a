"""Several hosts, tested: units in network namespaces of their own, a zenoh router in another
(needs root; the tests skip in one line where namespaces are not permitted)."""
