"""Built-in tool scripts (``--device script:NAME``): the careless references of the
built-in tasks and the liver's deep transection."""
