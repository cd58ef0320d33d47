--
-- PostgreSQL database dump
--


-- Dumped from database version 15.18 (Debian 15.18-0+deb12u1)
-- Dumped by pg_dump version 15.18 (Debian 15.18-0+deb12u1)

SET statement_timeout = 0;
SET lock_timeout = 0;
SET idle_in_transaction_session_timeout = 0;
SET client_encoding = 'UTF8';
SET standard_conforming_strings = on;
SELECT pg_catalog.set_config('search_path', '', false);
SET check_function_bodies = false;
SET xmloption = content;
SET client_min_messages = warning;
SET row_security = off;

SET default_tablespace = '';

SET default_table_access_method = heap;

--
-- Name: changes; Type: TABLE; Schema: public; Owner: -
--

CREATE TABLE public.changes (
    change_id bigint NOT NULL,
    session_id text NOT NULL COLLATE pg_catalog."C",
    object_id bigint NOT NULL,
    kind text NOT NULL,
    t double precision NOT NULL,
    label text NOT NULL,
    from_x double precision,
    from_y double precision,
    from_z double precision,
    to_x double precision,
    to_y double precision,
    to_z double precision,
    seq bigint NOT NULL,
    CONSTRAINT changes_check CHECK ((((from_x IS NULL) = (from_y IS NULL)) AND ((from_x IS NULL) = (from_z IS NULL)))),
    CONSTRAINT changes_check1 CHECK ((((to_x IS NULL) = (to_y IS NULL)) AND ((to_x IS NULL) = (to_z IS NULL)))),
    CONSTRAINT changes_kind_check CHECK ((kind = ANY (ARRAY['added'::text, 'moved'::text, 'removed'::text])))
);


--
-- Name: changes_change_id_seq; Type: SEQUENCE; Schema: public; Owner: -
--

ALTER TABLE public.changes ALTER COLUMN change_id ADD GENERATED ALWAYS AS IDENTITY (
    SEQUENCE NAME public.changes_change_id_seq
    START WITH 1
    INCREMENT BY 1
    NO MINVALUE
    NO MAXVALUE
    CACHE 1
);


--
-- Name: done_acks; Type: TABLE; Schema: public; Owner: -
--

CREATE TABLE public.done_acks (
    done_id bigint NOT NULL,
    session_id text NOT NULL COLLATE pg_catalog."C",
    stream_id text NOT NULL,
    seq bigint NOT NULL,
    ack bytea NOT NULL
);


--
-- Name: done_acks_done_id_seq; Type: SEQUENCE; Schema: public; Owner: -
--

ALTER TABLE public.done_acks ALTER COLUMN done_id ADD GENERATED ALWAYS AS IDENTITY (
    SEQUENCE NAME public.done_acks_done_id_seq
    START WITH 1
    INCREMENT BY 1
    NO MINVALUE
    NO MAXVALUE
    CACHE 1
);


--
-- Name: objects; Type: TABLE; Schema: public; Owner: -
--

CREATE TABLE public.objects (
    session_id text NOT NULL COLLATE pg_catalog."C",
    object_id bigint NOT NULL,
    change_seq bigint NOT NULL,
    version bigint NOT NULL,
    n_obs bigint NOT NULL,
    frames_seen bigint NOT NULL,
    first_seen bigint NOT NULL,
    last_seen bigint NOT NULL,
    resolution_m double precision NOT NULL,
    label_counts json NOT NULL,
    n_points integer NOT NULL,
    points bytea NOT NULL,
    embedding_dim integer,
    embedding_sum bytea,
    state text NOT NULL,
    first_seen_t double precision,
    last_seen_t double precision,
    stays bytea,
    label_embeddings bytea,
    CONSTRAINT objects_check CHECK (((label_embeddings IS NULL) OR ((embedding_dim > 0) AND ((length(label_embeddings) % (4 * embedding_dim)) = 0)))),
    CONSTRAINT objects_check1 CHECK ((length(points) = (12 * n_points))),
    CONSTRAINT objects_check2 CHECK (((embedding_dim IS NULL) = (embedding_sum IS NULL))),
    CONSTRAINT objects_check3 CHECK (((embedding_sum IS NULL) OR (length(embedding_sum) = (4 * embedding_dim)))),
    CONSTRAINT objects_state_check CHECK ((state = ANY (ARRAY['present'::text, 'removed'::text]))),
    CONSTRAINT objects_stays_check CHECK (((stays IS NULL) OR (((length(stays) % 52) = 0) AND (length(stays) <= 1664))))
);
ALTER TABLE ONLY public.objects ALTER COLUMN points SET STORAGE EXTERNAL;
ALTER TABLE ONLY public.objects ALTER COLUMN label_embeddings SET STORAGE EXTERNAL;


--
-- Name: schema_version; Type: TABLE; Schema: public; Owner: -
--

CREATE TABLE public.schema_version (
    singleton boolean DEFAULT true NOT NULL,
    version integer NOT NULL,
    CONSTRAINT schema_version_singleton_check CHECK (singleton)
);


--
-- Name: sessions; Type: TABLE; Schema: public; Owner: -
--

CREATE TABLE public.sessions (
    session_id text NOT NULL COLLATE pg_catalog."C",
    name text NOT NULL,
    mode text NOT NULL,
    perception text NOT NULL,
    knobs json NOT NULL,
    token_hash text NOT NULL,
    created_at double precision NOT NULL,
    frames bigint NOT NULL,
    keyframes bigint NOT NULL,
    bytes_in bigint NOT NULL,
    bytes_out bigint NOT NULL,
    next_object_id bigint NOT NULL,
    seq bigint NOT NULL,
    delta_floor bigint NOT NULL,
    last_used_at double precision NOT NULL,
    last_t double precision,
    last_pose bytea,
    sightings bigint DEFAULT 0 NOT NULL,
    owner text COLLATE pg_catalog."C",
    epoch bigint DEFAULT 0 NOT NULL,
    lease_until double precision,
    up text,
    up_source text,
    CONSTRAINT sessions_check CHECK (((up IS NULL) = (up_source IS NULL))),
    CONSTRAINT sessions_last_pose_check CHECK (((last_pose IS NULL) OR (length(last_pose) = 64))),
    CONSTRAINT sessions_up_check CHECK (((up IS NULL) OR (up = ANY (ARRAY['+x'::text, '-x'::text, '+y'::text, '-y'::text, '+z'::text, '-z'::text])))),
    CONSTRAINT sessions_up_source_check CHECK (((up_source IS NULL) OR (up_source = ANY (ARRAY['set'::text, 'inferred'::text]))))
);


--
-- Name: shards; Type: TABLE; Schema: public; Owner: -
--

CREATE TABLE public.shards (
    name text NOT NULL COLLATE pg_catalog."C",
    url text NOT NULL,
    heartbeat_at double precision NOT NULL
);


--
-- Name: tombstones; Type: TABLE; Schema: public; Owner: -
--

CREATE TABLE public.tombstones (
    session_id text NOT NULL COLLATE pg_catalog."C",
    object_id bigint NOT NULL,
    seq bigint NOT NULL
);


--
-- Data for Name: changes; Type: TABLE DATA; Schema: public; Owner: -
--

INSERT INTO public.changes (change_id, session_id, object_id, kind, t, label, from_x, from_y, from_z, to_x, to_y, to_z, seq) OVERRIDING SYSTEM VALUE VALUES (1, 'kitchen', 1, 'added', 2, 'label-1', NULL, NULL, NULL, 1, 0.5, -1, 1);
INSERT INTO public.changes (change_id, session_id, object_id, kind, t, label, from_x, from_y, from_z, to_x, to_y, to_z, seq) OVERRIDING SYSTEM VALUE VALUES (3, 'kitchen', 3, 'added', 4, 'label-3', NULL, NULL, NULL, 3, 0.5, -1, 1);
INSERT INTO public.changes (change_id, session_id, object_id, kind, t, label, from_x, from_y, from_z, to_x, to_y, to_z, seq) OVERRIDING SYSTEM VALUE VALUES (4, 'kitchen', 4, 'added', 5, 'label-4', NULL, NULL, NULL, 4, 0.5, -1, 1);
INSERT INTO public.changes (change_id, session_id, object_id, kind, t, label, from_x, from_y, from_z, to_x, to_y, to_z, seq) OVERRIDING SYSTEM VALUE VALUES (5, 'kitchen', 1, 'moved', 6, 'label-1', 1, 0.5, -1, 1.5, 0.5, -1, 2);
INSERT INTO public.changes (change_id, session_id, object_id, kind, t, label, from_x, from_y, from_z, to_x, to_y, to_z, seq) OVERRIDING SYSTEM VALUE VALUES (6, 'kitchen', 4, 'removed', 6.5, 'label-4', 4, 0.5, -1, NULL, NULL, NULL, 2);
INSERT INTO public.changes (change_id, session_id, object_id, kind, t, label, from_x, from_y, from_z, to_x, to_y, to_z, seq) OVERRIDING SYSTEM VALUE VALUES (7, 'kitchen', 5, 'added', 9, 'label-5', NULL, NULL, NULL, 5, 0.5, -1, 3);


--
-- Data for Name: done_acks; Type: TABLE DATA; Schema: public; Owner: -
--

INSERT INTO public.done_acks (done_id, session_id, stream_id, seq, ack) OVERRIDING SYSTEM VALUE VALUES (1, 'kitchen', 'left', 1, '\x61636b2d31');
INSERT INTO public.done_acks (done_id, session_id, stream_id, seq, ack) OVERRIDING SYSTEM VALUE VALUES (2, 'kitchen', 'left', 2, '\x61636b2d32');
INSERT INTO public.done_acks (done_id, session_id, stream_id, seq, ack) OVERRIDING SYSTEM VALUE VALUES (3, 'kitchen', 'right', 7, '\x0061636b2d37ff');


--
-- Data for Name: objects; Type: TABLE DATA; Schema: public; Owner: -
--

INSERT INTO public.objects (session_id, object_id, change_seq, version, n_obs, frames_seen, first_seen, last_seen, resolution_m, label_counts, n_points, points, embedding_dim, embedding_sum, state, first_seen_t, last_seen_t, stays, label_embeddings) VALUES ('kitchen', 2, 1, 1, 3, 2, 2, 3, 0.05, '{"label-2": 2, "chair": 1}', 6, '\xcf2ba6bfe9b27cbf76810e40434e0d4010ce2a3f8da4b03eb5ba1cbf97d055bfa6869b3f5b12323f0ebc963fb819c0bf1b736f3f205f093fca2f833e1cd69cbfc8bceabd3f3a52bf', 8, '\x7c9e4a3e63f3ffbfef61753f2ec0f23f2c501c3fba68843fdbe18d3e0bd180bf', 'present', 1, 2, '\x00000000000000400000000000001040000000400000003f000080bf0000803f00000000000000c0000040400000803f00000000', '\x8497cf3f33729e3ef6b05a3f25481e3fc6e8ea3e7b6ea43fa6396b3f28824ebf0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f');
INSERT INTO public.objects (session_id, object_id, change_seq, version, n_obs, frames_seen, first_seen, last_seen, resolution_m, label_counts, n_points, points, embedding_dim, embedding_sum, state, first_seen_t, last_seen_t, stays, label_embeddings) VALUES ('kitchen', 1, 2, 2, 4, 3, 1, 3, 0.025, '{"label-1": 3, "chair": 1}', 6, '\x258333bff61021c07b5c413fc161a03e8b941cc0d76400c0417bae3e14c28c3e933963bf4c22c13fa1af1c4069666d3f4a5b14bc7f30b8be37670f3e38de41bec4754cbfbb4e0f40', 8, '\x05b499bf4646533f8b05233f536f45be2a1f8c3f749920bfa9eb5f3feeb86b3f', 'present', 0.5, 2.5, '\x000000000000f03f00000000000000400000803f0000003f000080bf0000000000000000000000c0000000400000803f00000000', '\xddde073e661ab3bf54317cbd2c17a13f676ea13fff4d2dbf73905a3f68b43ebf0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f');
INSERT INTO public.objects (session_id, object_id, change_seq, version, n_obs, frames_seen, first_seen, last_seen, resolution_m, label_counts, n_points, points, embedding_dim, embedding_sum, state, first_seen_t, last_seen_t, stays, label_embeddings) VALUES ('kitchen', 4, 2, 2, 4, 3, 4, 6, 0.1, '{"label-4": 3, "chair": 1}', 6, '\x6f52d9bf74d84fbfd1652e3e273977bef3b731bfeef8823f9205babe56f7bcbe7787253fe05ec2bff64543bf863c98bf7cb9e5bf97ec1abf2a79ccbfdaff913f4163443fba28e1be', 8, '\x91f927c01574a33f1420f7bee6d0c3be57795fbfc528b7bd4458d53e904c4fbf', 'removed', 2, 4, '\x00000000000010400000000000002040000080400000003f000080bf0000404000000000000000c00000a0400000803f00000000', '\xe277f23efa5f2bbe465ff6bfbbe62a3fba492b40f7ac143f185c5e3ec32af73f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f');
INSERT INTO public.objects (session_id, object_id, change_seq, version, n_obs, frames_seen, first_seen, last_seen, resolution_m, label_counts, n_points, points, embedding_dim, embedding_sum, state, first_seen_t, last_seen_t, stays, label_embeddings) VALUES ('kitchen', 5, 3, 1, 3, 2, 5, 6, 0.125, '{"label-5": 2, "chair": 1}', 6, '\x8cf2d8bf29b6ab3f0ee5903e60db973fc60f913ffd41d5bd7f41093f1180064003bd7abf3b56e0bffa95183fe5ecc2bd9869593f660f1cc0a9f492bfcb537dbe1e66b8bf85ff073f', 8, '\x1022da3e3b7e98bf800793bf440a483f488b33bf9975b73eadfbe1bff1bd583f', 'present', 2.5, 3.5, '\x000000000000144000000000000024400000a0400000003f000080bf0000804000000000000000c00000c0400000803f00000000', '\x82d9d7bf0c5318c07812373b460a92bfc43296bff72c27bf4f505a3efc5ce53f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f');
INSERT INTO public.objects (session_id, object_id, change_seq, version, n_obs, frames_seen, first_seen, last_seen, resolution_m, label_counts, n_points, points, embedding_dim, embedding_sum, state, first_seen_t, last_seen_t, stays, label_embeddings) VALUES ('hall', 1, 1, 1, 3, 2, 1, 2, 0.025, '{"label-1": 2, "chair": 1}', 6, '\xc9c0e03ef7668d3f387be1bf3f1c70bf71cf50bf4402d5be63bdbcbef4cbc43e8dfbd8bf444fb9bd67f1074042e9d13f1ddb963f625cc53f1c805d3f673f84bf8464853fd7f9873f', 8, '\xe189083fe8019f3f0d3e3a3eece65f3ef763113f494f6e3e77f158bfde1bb33e', 'present', 0.5, 1.5, '\x000000000000f03f00000000000000400000803f0000003f000080bf0000000000000000000000c0000000400000803f00000000', '\x532b1f3f657205bf9636953ed1d63b3fe453763f1194d5be53a2183e9e0371bd0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f0000c07f');


--
-- Data for Name: schema_version; Type: TABLE DATA; Schema: public; Owner: -
--

INSERT INTO public.schema_version (singleton, version) VALUES (true, 6);


--
-- Data for Name: sessions; Type: TABLE DATA; Schema: public; Owner: -
--

INSERT INTO public.sessions (session_id, name, mode, perception, knobs, token_hash, created_at, frames, keyframes, bytes_in, bytes_out, next_object_id, seq, delta_floor, last_used_at, last_t, last_pose, sightings, owner, epoch, lease_until, up, up_source) VALUES ('empty', 'the empty', 'semanticxr', 'detections', '{"max_object_points_server": 2000, "skip_mapping_set": ["wall"], "x": null}', 'sha256:empty', 1600000000, 3, 0, 0, 0, 1, 0, 0, 1600000000, NULL, NULL, 0, NULL, 0, NULL, NULL, NULL);
INSERT INTO public.sessions (session_id, name, mode, perception, knobs, token_hash, created_at, frames, keyframes, bytes_in, bytes_out, next_object_id, seq, delta_floor, last_used_at, last_t, last_pose, sightings, owner, epoch, lease_until, up, up_source) VALUES ('kitchen', 'the kitchen', 'semanticxr', 'detections', '{"max_object_points_server": 2000, "skip_mapping_set": ["wall"], "x": null}', 'sha256:kitchen', 1700000001.5, 25, 3, 1000, 200, 6, 3, 0, 1750000010, 6.5, '\x000000002549123f2549923fb76ddb3f2549123e6edb363f4992a43fdbb6ed3f2549923eb76d5b3f6edbb63f00000040b76ddb3e0000803f9224c93f92240940', 4, 'shard-a', 1, 1750000030, '+y', 'set');
INSERT INTO public.sessions (session_id, name, mode, perception, knobs, token_hash, created_at, frames, keyframes, bytes_in, bytes_out, next_object_id, seq, delta_floor, last_used_at, last_t, last_pose, sightings, owner, epoch, lease_until, up, up_source) VALUES ('hall', 'Halle – Flur ✓', 'semanticxr', 'depth', '{"max_object_points_server": 2000, "skip_mapping_set": ["wall"], "x": null}', 'sha256:hall', 1700000000.25, 2, 0, 0, 0, 2, 1, 0, 1700000000.25, NULL, NULL, 0, NULL, 0, NULL, '-z', 'inferred');


--
-- Data for Name: shards; Type: TABLE DATA; Schema: public; Owner: -
--

INSERT INTO public.shards (name, url, heartbeat_at) VALUES ('shard-a', 'http://10.0.0.1:8000', 1750000020);
INSERT INTO public.shards (name, url, heartbeat_at) VALUES ('shard-b', 'http://10.0.0.2:8000', 1750000021);


--
-- Data for Name: tombstones; Type: TABLE DATA; Schema: public; Owner: -
--

INSERT INTO public.tombstones (session_id, object_id, seq) VALUES ('kitchen', 3, 2);
INSERT INTO public.tombstones (session_id, object_id, seq) VALUES ('kitchen', 4, 2);


--
-- Name: changes_change_id_seq; Type: SEQUENCE SET; Schema: public; Owner: -
--

SELECT pg_catalog.setval('public.changes_change_id_seq', 7, true);


--
-- Name: done_acks_done_id_seq; Type: SEQUENCE SET; Schema: public; Owner: -
--

SELECT pg_catalog.setval('public.done_acks_done_id_seq', 3, true);


--
-- Name: changes changes_pkey; Type: CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.changes
    ADD CONSTRAINT changes_pkey PRIMARY KEY (change_id);


--
-- Name: done_acks done_acks_pkey; Type: CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.done_acks
    ADD CONSTRAINT done_acks_pkey PRIMARY KEY (done_id);


--
-- Name: done_acks done_acks_session_id_stream_id_seq_key; Type: CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.done_acks
    ADD CONSTRAINT done_acks_session_id_stream_id_seq_key UNIQUE (session_id, stream_id, seq);


--
-- Name: objects objects_pkey; Type: CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.objects
    ADD CONSTRAINT objects_pkey PRIMARY KEY (session_id, object_id);


--
-- Name: schema_version schema_version_pkey; Type: CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.schema_version
    ADD CONSTRAINT schema_version_pkey PRIMARY KEY (singleton);


--
-- Name: sessions sessions_pkey; Type: CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.sessions
    ADD CONSTRAINT sessions_pkey PRIMARY KEY (session_id);


--
-- Name: shards shards_pkey; Type: CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.shards
    ADD CONSTRAINT shards_pkey PRIMARY KEY (name);


--
-- Name: tombstones tombstones_pkey; Type: CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.tombstones
    ADD CONSTRAINT tombstones_pkey PRIMARY KEY (session_id, object_id);


--
-- Name: changes_by_seq; Type: INDEX; Schema: public; Owner: -
--

CREATE INDEX changes_by_seq ON public.changes USING btree (session_id, seq);


--
-- Name: changes_by_t; Type: INDEX; Schema: public; Owner: -
--

CREATE INDEX changes_by_t ON public.changes USING btree (session_id, t);


--
-- Name: changes_in_order; Type: INDEX; Schema: public; Owner: -
--

CREATE INDEX changes_in_order ON public.changes USING btree (session_id, change_id);


--
-- Name: done_acks_in_order; Type: INDEX; Schema: public; Owner: -
--

CREATE INDEX done_acks_in_order ON public.done_acks USING btree (session_id, done_id);


--
-- Name: objects_by_state; Type: INDEX; Schema: public; Owner: -
--

CREATE INDEX objects_by_state ON public.objects USING btree (session_id, state, object_id, change_seq);


--
-- Name: sessions_by_last_use; Type: INDEX; Schema: public; Owner: -
--

CREATE INDEX sessions_by_last_use ON public.sessions USING btree (last_used_at);


--
-- Name: sessions_by_owner; Type: INDEX; Schema: public; Owner: -
--

CREATE INDEX sessions_by_owner ON public.sessions USING btree (owner);


--
-- Name: changes changes_session_id_fkey; Type: FK CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.changes
    ADD CONSTRAINT changes_session_id_fkey FOREIGN KEY (session_id) REFERENCES public.sessions(session_id) ON DELETE CASCADE;


--
-- Name: done_acks done_acks_session_id_fkey; Type: FK CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.done_acks
    ADD CONSTRAINT done_acks_session_id_fkey FOREIGN KEY (session_id) REFERENCES public.sessions(session_id) ON DELETE CASCADE;


--
-- Name: objects objects_session_id_fkey; Type: FK CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.objects
    ADD CONSTRAINT objects_session_id_fkey FOREIGN KEY (session_id) REFERENCES public.sessions(session_id) ON DELETE CASCADE;


--
-- Name: tombstones tombstones_session_id_fkey; Type: FK CONSTRAINT; Schema: public; Owner: -
--

ALTER TABLE ONLY public.tombstones
    ADD CONSTRAINT tombstones_session_id_fkey FOREIGN KEY (session_id) REFERENCES public.sessions(session_id) ON DELETE CASCADE;


--
-- PostgreSQL database dump complete
--


