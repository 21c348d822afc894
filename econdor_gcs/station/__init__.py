"""The ground station's MAVLink executor and its parts: the loop thread, the procedures
(start, return, land) done on evidence, what each vehicle sends, the missions it is given,
sample recovery and vehicles given up."""
