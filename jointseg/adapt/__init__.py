"""Learning from users' corrections (issue 66): the bundled network's last layers adapted to the
classes users gave, on the CPU, so that the next scans of the same site and sensor come out
right without a GPU or a better general network."""
