#!/bin/sh
# The broker of compose.yaml: sets the service's user "advisor" in the password file (kept in
# the mosquitto-auth volume with the devices' users) to MQTT_PASSWORD, then runs Mosquitto.
set -eu
: "${MQTT_PASSWORD:?MQTT_PASSWORD is not set}"
passwords=/mosquitto/auth/passwd
umask 077
touch "$passwords"
mosquitto_passwd -b "$passwords" advisor "$MQTT_PASSWORD"
chown mosquitto:mosquitto "$passwords"  # Mosquitto reads it as that user
exec /usr/sbin/mosquitto -c /mosquitto/config/mosquitto.conf
