"""`python -m abp_bringup.security_check`: refuse SROS2 asked for on a machine whose rmw
cannot do it, with a message that says so (scripts/start_graph.sh runs it first).

rcl reads `ROS_SECURITY_ENABLE` (security is on only for the exact value `true`),
`ROS_SECURITY_STRATEGY` (`Enforce`, else permissive) and `ROS_SECURITY_KEYSTORE` (with
the enclave, `ROS_SECURITY_ENCLAVE_OVERRIDE` or `--ros-args --enclave`). With the Fast DDS
of the PyPI wheels, built without DDS Security, what a node does then depends on the
keystore, and none of it is what the user asked for:

- an enclave with its files: node creation fails with rmw_fastrtps's "This Fast DDS
  version doesn't have the security libraries" (every node, every restart);
- Enforce without a usable enclave: `rclpy.init` fails with rcl's "SECURITY ERROR:
  directory ... does not exist" or "failed to initialize rcl: error not set";
- permissive (the default strategy) without an enclave: the node runs, unencrypted and
  unauthenticated, with no word about it.

The check asks the rmw itself: in a child process it creates a node with security on and
a throwaway keystore whose enclave holds placeholder files. An rmw without DDS Security
refuses with the message above; one with it gets as far as reading the placeholder
certificates and refuses those instead (or, should it accept them, creates the node).
Either way the user's keystore is never touched. Exit code 0 when security is not asked
for (unset, `false`, anything but `true`) or the rmw can do it; 2 with the reason
otherwise.
"""

import os
import subprocess
import sys
import tempfile

ENCLAVE_FILES = ('identity_ca.cert.pem', 'cert.pem', 'key.pem', 'permissions_ca.cert.pem',
                 'governance.p7s', 'permissions.p7s')
NO_SECURITY = "doesn't have the security libraries"   # rmw_fastrtps's words for it
PROBE_TIMEOUT_S = 60.0
# The probe: a node in its own process (rclpy.init reads the environment once).
PROBE = """
import rclpy
rclpy.init()
try:
    rclpy.create_node('abp_security_probe').destroy_node()
    print('node created')
except Exception as error:
    print(f'node refused: {error}')
finally:
    rclpy.try_shutdown()
"""


def security_requested(environ=None):
    """Whether rcl turns security on: ROS_SECURITY_ENABLE is exactly 'true'."""
    return (os.environ if environ is None else environ).get('ROS_SECURITY_ENABLE') == 'true'


def probe_rmw(environ=None):
    """(can the rmw do DDS Security, what the probe node said)."""
    env = dict(os.environ if environ is None else environ)
    with tempfile.TemporaryDirectory(prefix='abp-security-probe-') as keystore:
        enclave = os.path.join(keystore, 'enclaves', 'abp_probe')
        os.makedirs(enclave)
        for name in ENCLAVE_FILES:
            with open(os.path.join(enclave, name), 'w') as placeholder:
                placeholder.write('placeholder: not a certificate\n')
        env.update(ROS_SECURITY_ENABLE='true', ROS_SECURITY_STRATEGY='Enforce',
                   ROS_SECURITY_KEYSTORE=keystore, ROS_SECURITY_ENCLAVE_OVERRIDE='/abp_probe',
                   # The probe joins no graph: a domain of its own, this host only.
                   ROS_DOMAIN_ID='232', ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        env.pop('ROS_STATIC_PEERS', None)
        env.pop('ROS_DISCOVERY_SERVER', None)
        done = subprocess.run([sys.executable, '-c', PROBE], env=env, capture_output=True,
                              text=True, timeout=PROBE_TIMEOUT_S)
    said = (done.stdout + done.stderr).strip()
    return NO_SECURITY not in said, said


def refusal(environ=None):
    """The reason to refuse this environment, or None."""
    environ = os.environ if environ is None else environ
    if not security_requested(environ):
        return None
    capable, _ = probe_rmw(environ)
    if capable:
        return None
    strategy = environ.get('ROS_SECURITY_STRATEGY') or 'Permissive'
    return ("ROS_SECURITY_ENABLE=true asks for SROS2 (DDS Security), but this machine's "
            f'{environ.get("RMW_IMPLEMENTATION") or "rmw_fastrtps_cpp"} runs a Fast DDS built '
            'without it (the PyPI wheels\' Fast DDS: "This Fast DDS version doesn\'t have the '
            f'security libraries"). With ROS_SECURITY_STRATEGY={strategy} the nodes would '
            + ('fail to start.' if strategy == 'Enforce' else
               'fail to start with a keystore, or run unencrypted and unauthenticated without '
               'one.')
            + ' Unset ROS_SECURITY_ENABLE (or set it to false) to run without security, or '
            'run on ROS 2 Jazzy from apt, whose Fast DDS has DDS Security (docs/OFFBOARD.md, '
            '"Security").')


def main():
    reason = refusal()
    if reason:
        print(f'[start_graph] error: {reason}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
