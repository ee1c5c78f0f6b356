"""The words of ETG's XML formats: every element and attribute name of ESI (ETG.2000,
schemas 1.14 and 1.17) and ENI (ETG.2100, schema 1.3) files, and what ecatcfg does with it.

A name is handled in one of three ways (:data:`WORDS`):

- ``read``: read into the model where ETG places it (the ESI reader, ``esi/reader.py``, or
  the ENI reader's list, ``eni/contents.py``), where it may change what is sent;
- ``metadata``: it cannot change what a master sends or checks, wherever it appears:
  names, comments, texts and images for people, a tool's own data, descriptions of the
  hardware that the master reads from the slave itself;
- ``refused``: ecatcfg does not implement it and refuses it by name (``VoE`` InitCmds).

The ENI reader uses the table for what it finds where its list does not name it
(``eni/contents.py``): a ``metadata`` word there is a warning (text and JSON), anything
else is refused with its file, line and slave, since it may change a write, a check or the
cycle.  Attribute names are keyed ``@Name``; an element and an attribute of one name are two
words.  ``tests/test_vocabulary.py`` collects the names of the ETG schemas and of every ESI
and ENI file of both corpora and fails on one that is not here.

It lives with the ESI reader, the lowest layer that reads ETG's XML, so that both readers
can use it.
"""

from __future__ import annotations

from typing import Literal

Kind = Literal["read", "metadata", "refused"]


def _words(kind: Kind, why: str, names: str) -> dict[str, tuple[Kind, str]]:
    return {name: (kind, why) for name in names.split()}


# -- read into a model -------------------------------------------------------------------------

_ENI_READ = _words("read", "read by the ENI reader where eni/contents.py lists it", """
    Addr Ado Adp AoE Attribute AutoIncAddr BeforeSlave BitSize Ccs Cmd Cnt CoE Config
    CopyInfo CopyInfos CycleTime CycleTime0 CycleTime1 Cyclic DC Data DataLength Disabled
    DriveNo DstBitOffs Elements EoE ExternalDrivers FoE Frame GroupMemberCnt HotConnect IDN
    Identification IdentifyCmd Index Info InitCmd InitCmds InputDefaultData
    InputDefaultDataMask InputOffs Mailbox MailboxStates Master MaxFrameSize OpCode
    OutputDefaultData OutputDefaultDataMask OutputOffs PhysAddr Physics Port PreviousPort
    ProcessData ProcessImage ProductCode RNIC Recv Receive ReferenceClock Requires Retries RevisionNo
    Send SeparateIOUpdate SerialNo ShiftTime Slave SoE SrcBitOffs State SubIndex Timeout
    Transition Validate VendorId Sm0 Sm1 Sm2 Sm3 EtherCATConfig EncryptedEtherCATConfig
    DataMask Variable Inputs Outputs ByteSize BitOffs Type Enable StartAddress ControlByte
    MinSize MaxSize DefaultSize Virtual Watchdog RxPdo TxPdo Entry Exclude SubItem DataType
    BitLen Pdo StartAddr Count PollTime StatusBitAddr Start Length Destination EtherType
    MasterTimeAsRef
    @CycleTimeFactor @CycleTimeShiftFactor @DataLinkLayer @HotPlug @Version @Sm @Su
    @Fixed @Mandatory @Virtual @EnableIdentification @Value
""")

# Attributes with one meaning wherever they appear (eni/contents.py ANYWHERE).
_BY_MEANING: dict[str, tuple[Kind, str]] = {
    "@AdaptAutomatically": ("metadata", "the configurator may adapt the data to the PDO "
                            "configuration; the file holds the data it sends, as written"),
    "@CompleteAccess": ("read", "a CoE transfer of the whole object (complete access)"),
    "@Selected": ("read", "which of several alternatives is the one in use"),
    "@Type": ("read", "Validate@Type: how a read is compared (EQ, EQ_OR_G, the word-wise "
              "forms of ETG.2000's revision check); elsewhere the element's type"),
}

_ESI_READ = _words("read", "read into the ESI model (esi/reader.py)", """
    Access AddInfo ArrayInfo AssignActivate BackToInitTimeout BackToSafeopTimeout Backup
    BaseType BitLength BitStart CatNo Category Channel Class ConfigData CycleTimeSync0
    CycleTimeSync1 DataTypes Dc DcOpModeName Descriptions Device Devices Dictionary
    DictionaryFile EBusCurrent Eeprom Enum EnumInfo EtherCATInfo EtherCATModule Flags Fmmu
    Group GroupType Groups Id IdentificationAdo IdentificationReg134 InfoReference LBound
    MaxData MinData Module ModuleClass ModuleIdent ModulePdoGroup Modules Object Objects
    OpMode PdoMapping PreopTimeout ProfileNo RequestTimeout ResponseTimeout SM
    SafeopOpTimeout SdoAccess Setting ShiftTimeSync0 ShiftTimeSync1 Slot Slots Source
    StateMachine SubIdx Value Vendor Sm EtherCATInfoList DefaultData
    @Alignment @AssignToPdi @BitOffs @BitSize @Channel @Chn @ControlByte @Default
    @DefaultSize @DependOnSlot @DownloadModuleIdentList @DownloadModuleListTransition
    @DriveFollowsBit3Support @Enable @Factor @FixedAssignment @ID @IP @IgnoreFromBuildNo
    @Index @LcId @MAC @MaxInstances @MaxSize @MinInstances @MinSize @ModuleClass
    @ModuleIdent @ModulePdoGroup @OSFac @OSIndexInc @OSMax @OSMin @OneByteMode @OpOnly
    @OverwrittenByModule @PdoAssign @PdoConfig @PdoOrder @PdoUpload @PotentialReferenceClock
    @ProductCode @ProductRevision @ReadRestrictions @RevisionNo @RxPdo @SdoInfo
    @SegmentedSdo @SerialNo @SlotGroup @SlotIndexIncrement @SlotPdoIncrement @StartAddress
    SlotGroupData @DependOnSlotGroup @SlotGroupIndexIncrement @SlotGroupPdoIncrement
    @SubIndex @TimeStamp @TxPdo @UseFromBuildNo @VendorId @Watchdog @WriteRestrictions
    @UseLrdLwr
""")

# -- metadata: cannot change what is sent ------------------------------------------------------

_TEXT = _words("metadata", "a name, comment or text for people", """
    Name Comment Desc Description DisplayName Text TextId ToolTipText Hint Label MessageText
    ElementName Symbol Unit UnitType UnitTypes NameInResource ProductName Company
    CreatedBy Presentation Xml Properties Property DefaultString DefaultValue MinValue
    MaxValue BitMask Scaling FloatFormat ConvertValue Const_A Const_B Const_C Const_D
    @Name @DisplayName @DSType @UniqueName @slave_name @Ref @RefName @SortOrder
    @DScale @DefaultFactor @ChnFac @SwapData
    @SlotGroupIncrement
""")

_UI = _words("metadata", "how a configuration tool shows the device (images, dialogs, "
             "fonts, tabs, catalog entries)", """
    Image16x14 ImageData16x14 ImageFile16x14 URL DescriptionURL BkColour TextColour Bold Font
    FontId DialogElement DialogPosition DialogPositionEnd DialogPositionMiddle SettingsTab
    ShowOnDialog HideType AlternativeType SubDevice Sci ChannelCount ChannelInfo SubAddInfo
    NotationIndex OnlyForChannel IOModuleSubTypeInfo
    @Hideable @Invisible @TreeView @ShowHideableSubDevices @TabVersion @ChannelGroup
    @ChannelNo @ChannelCount @NoOfChannels @DS402Channels @ParentGroup @IdentifyModuleBy
    @AX2000 @PreserveOnlineData @Input @Idx @No @Size @ObjectsCount @EdsFile
""")

_DIAG = _words("metadata", "diagnosis texts and message tables, shown to people", """
    EtherCATDiag DiagClass DiagFile DiagMessage DiagMessages DiagReaction DiagReset DiagType
    DiagnosisCount DiagnosisStartIndex Cause CauseRemedy Remedy informationCount
    informationStartIndex Reserve1Count Reserve1StartIndex Reserve2Count Reserve2StartIndex
    ConfigCount ConfigStartIndex ReferenceId @DiagHistory
""")

_TOOL = _words("metadata", "a tool's own data (TwinCAT, Elmo, EC-Engineer, TwinSAFE "
               "editors), outside what ETG.2100 gives a master", """
    VendorSpecific VendorSpecificType TcSmExtension TcSmTComSupport Tool TwinCAT
    ElmoDC ElmoEditedPdo ElmoFmmu ElmoInit ElmoMaster ElmoPI ElmoSlaveInfo ElmoSlots
    ElmoSpecialResources ResID Manufacturer Esi Guid UserInits CoEInits UncheckInits
    ActiveOpMode Receive ShortSend EtherCATDict EoeMacIp AoeNetId TargetSpecific
    TwinSAFE TwinSAFELogic LogicPDO LogicType FBs FBSupportFlags1 FBSupportFlags2
    FeatureFlags External IOModuleAttribute DebugMemorySize SafetyMapping SafetyParaMapping
    SafetySettingsIndex slave
    @Guid @FileVersion @EncryptionVersion @Signature @Crc32 @SciVersion @TcSmClass
    @TcCfgModeSafeOp @noNamespaceSchemaLocation @AdsRouter @CreateGateway
    @GenerateOwnNetId @InitializeOwnNetId @Alias @SMNumber @ObjectsList @OpModeSelect
    @TotalIN @TotalOut @VarOffset @VarType @ModuleOD @SRA_Parameter
    @SRA_ParameterSupported @SafetyConnNumber @SafetyPdoType @AtLeastSoftwareVersion
    @DownloadModuleList @DownloadModuleAddressList @DefaultSettings
""")

_HARDWARE = _words("metadata", "a description of the hardware or its limits; the master "
                   "reads the slave itself (ESC registers, SII) and the ENI or topology "
                   "says what to configure", """
    Electrical Current Voltage MinVoltage MaxCurrent Resistance PowerSupply Connector
    Connections Up Us Su ESC EtherCATController ExecutionUnit Register Reg0108 Reg0400
    Reg0410 Reg0420 PhysicalPhyAddr RxDelay TxDelay EtherCATp DeviceFeature
    StationAliasSupported FmmuCount SmCount DpramSize StdInSize StdOutSize MaxPorts
    MaxFrames MaxMACs MaxEtherCATSize MaxFramDataSize MaxProcessImageSize
    MaxNearProcessImageSize MaxMappingCodeSize MaxConnectionCRCs MaxFSoEMessageSize
    MaxFSoEUserParaSize MaxProfisafeMasterConnections MaxProfisafeMessageSize
    MaxProfisafeSlaveConnections MaxSafeLogicPages MaxSafeReplaceValuePages
    MaxSafeUserParaPages MaxTwinSAFESCMasterConnections ChToIoCount Oversampling Size
    SlotNo ModuleBaseType ModuleIdents Pdos PdoMapIndexOrder EnableFlag DataString
    DataUDINT DataUINT Behavior DcCycleTime SyncType SubMode OperationMode
    @MaxSlotCount @MaxSlotGroupCount @MinCycleTime @MinAfterSync @MinBeforeFrame
    @ExternalRefClock @UnknownFRMW @Unknown64Bit @SdoUploadWithMaxLength
    @Dynamic @RealTimeMode @TimeDistribution @TimeLoopControlOnly @InputDelayTime
    @OutputDelayTime @FrameRepeatSupport @StartToInit @StartToPreop @StartToSafeop
    @StartToSafeopNoSync
""")

_HINTS = _words("metadata", "a hint to the configurator; what it decided is written in "
                "the ENI (InitCmds, SyncManagers, PDOs) or chosen in the topology", """
    AlternativeSmMapping ExcludedPdo ExcludedSm ReusePdosAsTargetSettings ErrorHandling
    AutoRestoreAfterWcOk SetFrameRepeatTime BootStrap Profile Protocol ProductRevision
    RevisionReal DeviceId PotentialReferenceClock NetId IndexType OwnerPhysAddr MaxErrors
    @DependOnInputState @Fallback @PreviousDevice @PreviousPortNo @SeparateFrame
    @SeparateSu @IgnoreFmmuSu @IgnorePdoSu @CheckProductCode @CheckRevisionNo
    @CheckSerialNo @AdaptAutomatically @Physics @Segment
    @SegmentSubIndex @Sm2 @Sm3
""")

_HOST = _words("metadata", "the master's host-side settings (its interface, tasks, "
               "periods): no command to a slave", """
    NIC TaskId Priority AutoRecoveryTimeout DCUserShiftTime InitialMasterState MBCycleTime
    ProcessImageUpdatePeriod StatisticsUpdatePeriod
""")

# -- refused by name ---------------------------------------------------------------------------

_REFUSED = _words("refused", "not implemented: refused by name (eni/contents.py)", """
    VoE SlotSelections
""")

WORDS: dict[str, tuple[Kind, str]] = {}
for _table in (_REFUSED, _HOST, _HINTS, _HARDWARE, _TOOL, _DIAG, _UI, _TEXT, _ESI_READ,
               _ENI_READ, _BY_MEANING):
    WORDS.update(_table)          # later tables win: a word read somewhere is "read"


def kind_of(name: str, attribute: bool = False) -> Kind | None:
    """What ecatcfg does with the element (or, ``attribute``, the attribute) ``name``;
    ``None`` for a word of neither format."""
    word = WORDS.get(f"@{name}" if attribute else name)
    return None if word is None else word[0]


def is_metadata(name: str, attribute: bool = False) -> bool:
    """Whether ``name`` cannot change what is sent, wherever it appears."""
    return kind_of(name, attribute) == "metadata"
