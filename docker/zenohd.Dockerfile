# The router image without a registry: zenohd built by cargo (tests/setup.d/zenohd.sh) on the local
# Debian base image. docker/offline.sh builds it from a context holding just that binary:
#   docker build --build-arg BASE_IMAGE=dronesim-local/python:3.11-bookworm -t dronesim-local/zenoh:1.10.2 CONTEXT
# It runs like eclipse/zenoh: the command is zenohd's arguments (compose: -c /etc/zenoh/zenohd.json5),
# and it has a shell and grep for the compose health check.
ARG BASE_IMAGE
FROM ${BASE_IMAGE}
COPY zenohd /usr/local/bin/zenohd
EXPOSE 7447
ENV RUST_LOG=info
ENTRYPOINT ["/usr/local/bin/zenohd"]
