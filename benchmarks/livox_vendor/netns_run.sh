ip link set lo up; ip link add v0 type veth peer name v1; ip addr add 10.99.0.1/24 dev v0; ip addr add 10.99.0.2/24 dev v1; ip link set v0 up; ip link set v1 up
sleep 1
cd "$(dirname "$0")/../.." && timeout 60 "${PYTHON:-python}" "$@"
