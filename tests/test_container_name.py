"""A node's default name in a Docker container (node/container_name.py, node/settings.py): the PTR
query and the parse of Docker's answer, the project taken off, a Swarm template Compose left
unexpanded ignored. The real thing, in containers under Compose and Swarm: tests/test_docker.py."""

from __future__ import annotations

import os
import socket

import pytest

import node.settings
from node.container_name import ptr_answer, ptr_query, without_project
from node.settings import default_name, parse_settings

#: Docker 20.10's embedded DNS server answering query 1, the PTR of 172.18.0.3 (a node container of
#: the Compose v1 project ``dnsprobe``), as received.
DOCKER_REPLY = (b"\x00\x01\x81\x80\x00\x01\x00\x01\x00\x00\x00\x00\x013\x010\x0218\x03172\x07in-addr\x04arpa\x00"
                b"\x00\x0c\x00\x01\x013\x010\x0218\x03172\x07in-addr\x04arpa\x00\x00\x0c\x00\x01\x00\x00\x02X\x00\""
                b"\x0fdnsprobe_node_1\x10dnsprobe_default\x00")


def test_the_query_asks_what_docker_answered():
    query = ptr_query("172.18.0.3", 1)
    assert query == b"\x00\x01\x01\x00\x00\x01\x00\x00\x00\x00\x00\x00" + DOCKER_REPLY[12:len(query)]


def test_dockers_answer_names_the_container_and_its_network():
    assert ptr_answer(DOCKER_REPLY, 1) == "dnsprobe_node_1.dnsprobe_default"
    assert ptr_answer(DOCKER_REPLY, 2) is None, "another query's answer"


def test_a_compressed_answer_name_is_followed():
    question = ptr_query("10.0.0.7", 9)[12:]
    suffix = 12 + question.index(b"\x07in-addr")
    target = b"\x06node_3\xc0" + bytes([suffix])   # "node_3" then the question's "in-addr.arpa"
    answer = b"\xc0\x0c" + b"\x00\x0c\x00\x01\x00\x00\x00\x3c" + len(target).to_bytes(2, "big") + target
    reply = b"\x00\x09\x81\x80\x00\x01\x00\x01\x00\x00\x00\x00" + question + answer
    assert ptr_answer(reply, 9) == "node_3.in-addr.arpa"


@pytest.mark.parametrize("reply", [
    DOCKER_REPLY[:-5],                                        # cut short
    DOCKER_REPLY[:3] + b"\x83" + DOCKER_REPLY[4:],            # NXDOMAIN, as Swarm answers for a task
    DOCKER_REPLY[:2] + b"\x01" + DOCKER_REPLY[3:],            # a query, not a reply
    b"\x00\x01\x81\x80\x00\x01\x00\x00\x00\x00\x00\x00" + DOCKER_REPLY[12:],  # no answer record
    b"\x00\x01\x81\x80\x00\x01\x00\x00\x00\x00\x00\x00\xc0\x0c",  # a name that points at itself
    b"",
])
def test_bad_answers_name_nothing(reply):
    assert ptr_answer(reply, 1) is None


@pytest.mark.parametrize(("dns_name", "name"), [
    ("dnsprobe_node_1.dnsprobe_default", "node_1"),               # Compose v1
    ("tessera-test-1a2b-node-3.tessera-test-1a2b_default", "node-3"),  # Compose v2
    ("tessera_node_1.backend", "tessera_node_1"),                   # another network: whole
    ("other_node_1.tessera_default", "other_node_1"),
    ("tessera_.tessera_default", "tessera_"),
])
def test_the_project_is_taken_off(dns_name, name):
    assert without_project(dns_name) == name


@pytest.fixture
def outside_docker(monkeypatch, tmp_path):
    """This process as outside a container, wherever the tests run."""
    monkeypatch.setattr(node.settings, "DOCKER_MARKER", tmp_path / "no-dockerenv")


def test_outside_a_container_the_name_is_hostname_and_pid(outside_docker):
    name = default_name()
    assert name == f"{socket.gethostname()}-{os.getpid()}"


def test_an_unexpanded_swarm_template_gives_the_default_name_and_an_expanded_one_is_taken(outside_docker):
    assert parse_settings([], {"TESSERA_NAME": "{{.Service.Name}}.{{.Task.Slot}}"}).name.startswith(
        socket.gethostname() + "-")
    assert parse_settings([], {"TESSERA_NAME": "tessera_node.2"}).name == "tessera_node.2"
    assert parse_settings(["--name", "left"], {"TESSERA_NAME": "tessera_node.2"}).name == "left"
