"""MJCF of a hovering AUV shaped like the HAUV: a 130 kg box, neutrally buoyant (so no net
gravity), thrusters for surge, sway, heave and yaw through its centre of mass, and linear drag.

MJX's JAX backend ignores MuJoCo's ellipsoid fluid model, so drag is joint damping on the free
joint: -150 N per m/s and -150 N m per rad/s, which also keeps pitch and roll settled."""

HAUV_XML = """
<mujoco model="hauv">
  <option timestep="0.05" gravity="0 0 0" integrator="Euler"/>
  <worldbody>
    <body name="hauv" pos="0 0 0">
      <joint name="free" type="free" damping="150"/>
      <geom name="hull" type="box" size="0.8 0.5 0.3" mass="130"/>
      <site name="thrusters" pos="0 0 0"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="surge" site="thrusters" gear="1 0 0 0 0 0" ctrllimited="true" ctrlrange="-150 150"/>
    <motor name="sway" site="thrusters" gear="0 1 0 0 0 0" ctrllimited="true" ctrlrange="-150 150"/>
    <motor name="heave" site="thrusters" gear="0 0 1 0 0 0" ctrllimited="true" ctrlrange="-150 150"/>
    <motor name="yaw" site="thrusters" gear="0 0 0 0 0 1" ctrllimited="true" ctrlrange="-60 60"/>
  </actuator>
</mujoco>
"""
